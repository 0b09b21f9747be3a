"""The epoch benchmark's load (``bench/load.py``) and a smoke run of the benchmark itself."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from bench import bench_epoch
from bench.load import Load, Platform, RecordedDemand, SpreadDemand
from bench.report import ROOT
from services.model import RiderId, RiderMatch, TaskAssignment, TaskId, TaxiId
from tests.citymaker import grid_city


def _platform(riders: int = 3, tasks: int = 2) -> Platform:
    city = grid_city(5, 100.0)  # 10 m/s: an edge of 100 m takes 10 s
    nodes = np.arange(city.network.n_nodes, dtype=np.int64)
    demand = RecordedDemand(nodes, nodes[::-1].copy(), nodes[:4])
    return Platform(city, Load(2, 1, riders, tasks, seed=3), demand)


def test_taxis_continue_along_their_committed_paths_and_are_vacant_at_the_end() -> None:
    """A taxi given a path at one epoch is, at the next (200 s later), at the node the path reached by then,
    and busy while the path goes on; at its end it is vacant where the path ended."""
    plat = _platform()
    snap, _ = plat.next_epoch()
    t = snap.taxis[0]
    # along the south side and up the east side (8 edges), back, and again: 40 edges, 400 s (the service
    # plans paths from the taxi's node; the platform drives whatever path it is given)
    there = [0, 1, 2, 3, 4, 9, 14, 19, 24]
    back = there[::-1][1:]
    long_path = tuple(there + back + there[1:] + back + there[1:])
    assert len(long_path) == 41
    rid = snap.riders[0].id
    match = RiderMatch(2, t.id, rid, 0.0, 0.0, 0.0, 0.0, 0.0, long_path, ())
    plat.apply([match], [], [])
    snap1, _ = plat.next_epoch()
    moved = next(x for x in snap1.taxis if x.id == t.id)
    assert not moved.vacant and moved.node == long_path[20]  # 200 s: 20 edges along
    assert rid not in {r.id for r in snap1.riders}  # served
    snap2, _ = plat.next_epoch()
    done = next(x for x in snap2.taxis if x.id == t.id)
    assert done.vacant and done.node == long_path[-1]


def test_riders_wait_until_served_or_expired_and_new_requests_fill_the_list() -> None:
    """Each epoch posts the scenario's rider count: the riders still waiting plus new requests; the expired
    ones the service names leave; every epoch brings the scenario's new tasks, with fresh ids."""
    plat = _platform(riders=4, tasks=2)
    snap, tasks = plat.next_epoch()
    assert len(snap.riders) == 4 and len(tasks) == 2
    first = [r.id for r in snap.riders]
    plat.apply([], [], [first[0]])
    snap1, tasks1 = plat.next_epoch()
    ids = [r.id for r in snap1.riders]
    assert len(ids) == 4 and first[0] not in ids and set(first[1:]) <= set(ids)
    assert all(
        snap1.time_s - 200.0 <= r.requested_at_s <= snap1.time_s for r in snap1.riders if r.id not in first
    )
    assert {t.id for t in tasks1}.isdisjoint({t.id for t in tasks})


def test_a_step3_route_moves_its_taxi_too() -> None:
    plat = _platform()
    snap, _ = plat.next_epoch()
    t = snap.taxis[1]
    path = (5, 6, 7)
    a = TaskAssignment(t.id, TaskId("k0-0"), path, (), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    plat.apply([], [a], [RiderId("nobody")])
    snap1, _ = plat.next_epoch()
    assert next(x for x in snap1.taxis if x.id == t.id).node == path[-1]
    assert TaxiId("o0") in {x.id for x in snap1.taxis}


def test_under_the_heaviest_load_every_taxi_is_vacant_where_its_path_took_it() -> None:
    """With ``all_vacant`` a taxi given a path is posted vacant at the next epoch, at the node the path
    reached by then (200 s: 20 edges of 10 s along), not busy until the path ends."""
    city = grid_city(5, 100.0)
    plat = Platform(city, Load(2, 1, 2, 1, seed=3, all_vacant=True), SpreadDemand(city))
    snap, _ = plat.next_epoch()
    assert all(t.vacant for t in snap.taxis)
    t = snap.taxis[0]
    there = [0, 1, 2, 3, 4, 9, 14, 19, 24]
    path = tuple(there + there[::-1][1:] + there[1:] + there[::-1][1:])
    plat.apply([RiderMatch(1, t.id, snap.riders[0].id, 0.0, 0.0, 0.0, 0.0, 0.0, path, ())], [], [])
    snap1, _ = plat.next_epoch()
    moved = next(x for x in snap1.taxis if x.id == t.id)
    assert moved.vacant and moved.node == path[20]
    assert all(x.vacant for x in snap1.taxis)


def test_spread_demand_draws_over_the_whole_network() -> None:
    """Origins, destinations, POIs and taxi starts are drawn uniformly from all the nodes: over many draws
    every node of a small network comes up, each about equally often."""
    city = grid_city(5, 100.0)
    d = SpreadDemand(city)
    rng = np.random.default_rng(1)
    o, dst = d.trips(rng, 5000)
    for nodes in (o, dst, d.pois(rng, 5000), d.taxi_starts(rng, 5000)):
        counts = np.bincount(nodes, minlength=city.network.n_nodes)
        assert counts.min() > 120 and counts.max() < 280  # 200 expected per node


@pytest.mark.slow
def test_the_benchmark_times_a_baseline_checkout_on_the_same_epochs() -> None:
    """``--baseline DIR`` times DIR's ``decide`` in a process of its own on the same epochs and checks its
    decisions against this checkout's (here DIR is this checkout itself)."""
    r = bench_epoch.run_inprocess(bench_epoch.SCENARIOS["paper"], 2, baseline=ROOT)
    assert len(r["latency_baseline"]) == 2 and all(x > 0 for x in r["latency_baseline"])
    assert r["baseline"] == str(ROOT.resolve())


@pytest.mark.slow
def test_a_tiny_paper_run_of_the_epoch_benchmark(capsys: pytest.CaptureFixture[str]) -> None:
    """Two paper epochs in-process beside the floor, without writing the report: each has a latency on
    default threads and on one (their decisions checked equal inside), a floor and the phases."""
    assert bench_epoch.main(["--scenario", "paper", "--epochs", "2", "--no-http", "--no-write"]) == 0
    out = capsys.readouterr().out
    assert out.count("[paper] epoch ") == 2
    r = bench_epoch.run_inprocess(bench_epoch.SCENARIOS["paper"], 2)
    for key in ("latency", "latency_1thread", "floor"):
        assert len(r[key]) == 2
    assert set(r["phases_ms"]) == set(bench_epoch.PHASES)
    assert len(r["digests"]) == 3


@pytest.mark.slow
def test_a_tiny_run_of_the_heavy_grid_scenario() -> None:
    """The heaviest load on the 53-minute grid (no reach applies there): one timed epoch in-process, every
    instrumented taxi vacant, decisions equal on one thread and two (checked inside)."""
    sc = bench_epoch.SCENARIOS["grid53-heavy"]
    r = bench_epoch.run_inprocess(sc, 1)
    assert len(r["latency"]) == 1 and r["city_size"][0] == 22_500
    assert r["step3_taxis_median"] > 0


@pytest.mark.slow
def test_a_tiny_http_run_reports_the_api_and_the_whole_services_peak_memory() -> None:
    """One timed paper epoch over HTTP on the real service, its fleet worker asked to solve after the first
    epoch: the round trip, the server's solve and both peaks are reported, and the target lines say them."""
    h = bench_epoch.run_http(bench_epoch.SCENARIOS["paper"], 1, worker=True, worker_wait_s=0.0)
    assert len(h["latency"]) == len(h["server_solve"]) == 1 and len(h["digests"]) == 2
    # the worker's processes share library pages with the API: their RSS sum counts them in each
    assert 100.0 < h["server_peak_rss_mb"] <= h["service_peak_rss_sum_mb"]
    assert 100.0 < h["service_peak_pss_mb"] < h["service_peak_rss_sum_mb"]
    assert h["worker_solved"] and h["worker_city"] == "chengdu"  # a bundled city: its seeded history
    r: dict[str, Any] = {"inprocess": {"p99_ms": 1.0}, "floor": {"p99_ms": 1.0}, "http": {"p99_ms": 1.0}}
    r |= {"http_over_solve_pct": 1.0, "http_minus_solve": {"p50_ms": 1.0, "p99_ms": 1.0}}
    r |= {
        k: h[k]
        for k in (
            "server_peak_rss_mb",
            "service_peak_pss_mb",
            "service_peak_rss_sum_mb",
            "worker",
            "worker_solve_over",
            "worker_solved",
            "worker_city",
            "ready_s",
        )
    }
    line = bench_epoch._facts("metro250k", r)
    assert f"API process peak RSS {h['server_peak_rss_mb']:.0f} MB (target <= 1024 MB" in line
    whole = f"the whole service's peak {h['service_peak_pss_mb']:.0f} MB (the sum of its processes' PSS"
    assert whole in line
    assert "with the fleet worker's solve of chengdu (this city has too little history" in line
    assert f"their RSS sum {h['service_peak_rss_sum_mb']:.0f} MB) (target <= 1536 MB" in line
