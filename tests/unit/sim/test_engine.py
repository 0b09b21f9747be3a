"""The simulator and its KPIs on hand-solvable line cities (36 km/h: 100 m take 10 s; epochs 200 s)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import pytest

from services.city import DispatchParams, Horizon
from services.model import IntervalKey, Snapshot, Task, TaskId
from services.sim.demand import DemandSet, Request, demand_on_date
from services.sim.drift import DriftMap
from services.sim.engine import SimConfig, poi_tasks, simulate
from services.sim.kpi import design_kpi, price_of_sensing, run_kpis
from services.sim.local import LocalDispatcher, Outcome
from tests.citymaker import T0, make_city

DATE = "2026-11-23"  # T0 is 08:00 UTC of this day


def line_city(n: int = 5, spacing_m: float = 100.0, **kw: object):
    nodes = {i: (i * spacing_m, 0.0) for i in range(n)}
    edges = [(i, i + 1) for i in range(n - 1)]
    return make_city(nodes, edges, horizon=Horizon(timezone="UTC"), **kw)  # type: ignore[arg-type]


def demand(reqs: Sequence[tuple[str, float, int, int]]) -> DemandSet:
    return DemandSet("test", DATE, tuple(Request(i, T0 + t, o, d) for i, t, o, d in reqs), "hand")


class Recording:
    """A dispatcher that records the snapshots it was shown."""

    def __init__(self, inner: LocalDispatcher) -> None:
        self.inner = inner
        self.snapshots: list[Snapshot] = []

    def add_tasks(self, tasks: Sequence[Task]) -> None:
        self.inner.add_tasks(tasks)

    def epoch(self, snapshot: Snapshot) -> Outcome:
        self.snapshots.append(snapshot)
        return self.inner.epoch(snapshot)

    def tasks(self) -> list[Task]:
        return self.inner.tasks()

    def interval_counts(self, k: IntervalKey) -> np.ndarray:
        return self.inner.interval_counts(k)


def test_horizon_has_72_epochs_from_the_start() -> None:
    city = line_city()
    rec = Recording(LocalDispatcher(city))
    trace = simulate(city, demand([]), [], SimConfig(0, 1, 0, drift=False), rec, start_nodes=[0])
    assert len(trace.epochs) == 72 == len(rec.snapshots)
    assert [s.time_s - T0 for s in rec.snapshots[:3]] == [0.0, 200.0, 400.0]
    assert trace.start_s == T0 and trace.end_s == T0 + 4 * 3600


def test_a_short_run_is_the_start_of_the_whole_run() -> None:
    city = line_city(n=12)
    reqs = [(f"r{i}", 90.0 * i + 5, (3 * i) % 12, (5 * i + 4) % 12) for i in range(30)]
    tasks = [Task(TaskId("poi"), 11, T0 + 100)]
    config = SimConfig(1, 1, 1, seed=4)  # drift on: its seeded draws must line up too
    full = simulate(city, demand(reqs), tasks, config, LocalDispatcher(city))
    short = simulate(city, demand(reqs), tasks, config, LocalDispatcher(city), n_epochs=5)
    untimed = [dataclasses.replace(e, solve_ms=0.0) for e in (*short.epochs, *full.epochs[:5])]
    assert len(short.epochs) == 5 and untimed[:5] == untimed[5:]
    assert short.assignments == tuple((t, a) for t, a in full.assignments if t < T0 + 1000)
    assert short.end_s == T0 + 5 * 200 and full.end_s == T0 + 4 * 3600
    posted = {r.id for r in short.riders}
    assert posted == {f"r{i}" for i in range(30) if 90 * i + 5 <= 800}  # requested by the 5th epoch
    assert short.n_unposted == 30 - len(posted)
    with pytest.raises(ValueError, match="n_epochs"):
        simulate(city, demand(reqs), tasks, config, LocalDispatcher(city), n_epochs=73)


def test_demand_on_another_date_keeps_the_times_from_the_start() -> None:
    d = demand([("a", 50, 2, 4), ("b", 3600, 4, 0)])
    hz = Horizon(timezone="America/New_York")  # 2026-03-08 has 23 hours: the shift is not whole days
    moved = demand_on_date(d, hz, "2026-03-09")
    shift = hz.start_s("2026-03-09") - hz.start_s(DATE)
    assert moved.date == "2026-03-09" and moved.generator == d.generator
    assert [(r.id, r.time_s - shift, r.origin) for r in moved.requests] == [
        (r.id, r.time_s, r.origin) for r in d.requests
    ]


def test_ordinary_taxi_serves_two_riders_with_exact_waits() -> None:
    city = line_city()
    d = demand([("a", 50, 2, 4), ("b", 300, 4, 0)])
    rec = Recording(LocalDispatcher(city))
    trace = simulate(city, d, [], SimConfig(0, 1, 0, drift=False), rec, start_nodes=[0])
    a, b = trace.riders
    # a: posted at the 200 s epoch, pickup 200 m = 20 s -> wait 150 + 20
    assert (a.matched_at_s, a.step, a.pickup_s, a.wait_s) == (T0 + 200, 2, 20.0, 170.0)
    # the taxi drops a at node 4 at 200 + 40 s; b (requested at 300 s at node 4) is picked up at once at 400 s
    assert (b.matched_at_s, b.pickup_s, b.wait_s) == (T0 + 400, 0.0, 100.0)
    # the taxi was busy at node 4? no: the trip ended at 240 s, before the 400 s epoch; vacant at node 4
    taxi = rec.snapshots[2].taxis[0]
    assert (taxi.node, taxi.vacant) == (4, True)
    k = run_kpis(city, trace)
    assert (k.n_requests, k.n_matched, k.n_step2, k.riders_lost) == (2, 2, 2, 0)
    assert k.matching_rate == 1.0 and k.avg_wait_s == 135.0 and k.total_wait_s == 270.0
    assert k.hours[0].requests == 2 and k.hours[1].requests == 0


def test_busy_taxi_is_reported_at_the_last_node_it_reached() -> None:
    city = line_city(n=40)  # 3.9 km of road: the trip 0 -> 39 takes 390 s
    d = demand([("a", 0, 0, 39)])
    rec = Recording(LocalDispatcher(city))
    simulate(city, d, [], SimConfig(0, 1, 0, drift=False), rec, start_nodes=[0])
    at_200 = rec.snapshots[1].taxis[0]
    assert (at_200.node, at_200.vacant) == (20, False)  # 200 s at 10 s per node
    at_400 = rec.snapshots[2].taxis[0]
    assert (at_400.node, at_400.vacant) == (39, True)


def test_rider_out_of_reach_leaves_after_patience() -> None:
    city = line_city(n=40)  # radius 2 km: node 0 cannot reach a rider at node 39 (3.9 km)
    d = demand([("far", 10, 39, 38)])
    trace = simulate(city, d, [], SimConfig(0, 1, 0, drift=False), LocalDispatcher(city), start_nodes=[0])
    (r,) = trace.riders
    assert r.matched_at_s is None and r.left_at_s == T0 + 800  # 790 s > 600 s patience first at 800 s
    k = run_kpis(city, trace)
    assert (k.riders_lost, k.riders_unserved, k.matching_rate) == (1, 1, 0.0)


def test_step3_route_completes_the_task_and_prices_it() -> None:
    city = line_city()
    tasks = [Task(TaskId("poi"), 4, T0)]
    rec = Recording(LocalDispatcher(city))
    trace = simulate(city, demand([]), tasks, SimConfig(1, 0, 1, drift=False), rec, start_nodes=[0])
    ((t, a),) = trace.assignments
    assert t == T0 and a.path == (0, 1, 2, 3, 4) and a.length_m == pytest.approx(400.0)
    assert a.cost_cny == pytest.approx(1.5 * 0.4)
    (task,) = trace.tasks
    assert (task.status, task.mode, task.completed_at_s) == ("completed", "active", pytest.approx(T0 + 40))
    assert (rec.snapshots[1].taxis[0].node, rec.snapshots[1].taxis[0].vacant) == (4, True)
    k = run_kpis(city, trace)
    assert (k.n_completed, k.n_active, k.completion_rate) == (1, 1, 1.0)
    assert k.mean_delay_s == pytest.approx(40.0)
    assert k.design_kpi == pytest.approx(0.6 / 4.0)  # one instrumented taxi over 4 hours
    assert k.hours[0].design_kpi == pytest.approx(0.6) and k.hours[1].monitoring_cost_cny == 0.0
    # the route crossed the one cell of this 400 m city in the first hour: coverage 1 then 0
    assert [h.coverage_rate for h in k.hours] == [1.0, 0.0, 0.0, 0.0]
    assert k.coverage_rate == 0.25


def test_active_sensing_off_leaves_the_task_unmonitored() -> None:
    params = DispatchParams(speed_kmh=36.0, active_sensing=False)
    city = line_city(params=params)
    tasks = [Task(TaskId("poi"), 4, T0)]
    trace = simulate(
        city, demand([]), tasks, SimConfig(1, 0, 1, drift=False), LocalDispatcher(city), start_nodes=[0]
    )
    k = run_kpis(city, trace)
    assert trace.assignments == () and k.n_completed == 0 and k.completion_rate == 0.0
    assert k.tasks[0].completed_at_s is None and k.monitoring_cost_cny == 0.0


def test_wait_only_reports_no_instrumented_taxi() -> None:
    city = line_city()
    d = demand([("a", 50, 2, 4)])
    rec = Recording(LocalDispatcher(city))
    trace = simulate(
        city,
        d,
        [Task(TaskId("poi"), 4, T0)],
        SimConfig(1, 0, 1, drift=False, wait_only=True),
        rec,
        start_nodes=[0],
    )
    assert all(not t.instrumented for s in rec.snapshots for t in s.taxis)
    k = run_kpis(city, trace)
    assert k.n_step2 == 1 and k.n_step1 == 0 and k.gamma == 0.0 and k.n_active == 0


def test_price_of_sensing_is_the_difference_to_the_baseline() -> None:
    city = line_city()
    d = demand([("a", 50, 2, 4), ("b", 300, 4, 0)])
    run = run_kpis(
        city, simulate(city, d, [], SimConfig(0, 1, 0, drift=False), LocalDispatcher(city), start_nodes=[0])
    )
    base = run_kpis(
        city, simulate(city, d, [], SimConfig(0, 1, 0, drift=False), LocalDispatcher(city), start_nodes=[4])
    )
    p = price_of_sensing(run.scalars(), base.scalars())
    assert p["extra_wait_s"] == pytest.approx(run.total_wait_s - base.total_wait_s)
    assert p["extra_avg_wait_s"] == pytest.approx(run.avg_wait_s - base.avg_wait_s)
    assert p["extra_riders_lost"] == 0.0 and p["matching_rate_drop"] == 0.0
    nobody = {**base.scalars(), "avg_wait_s": None}  # as read back from JSON when nobody was matched
    assert price_of_sensing(run.scalars(), nobody)["extra_avg_wait_s"] is None


def test_same_seed_same_run_other_seed_other_starts() -> None:
    city = line_city(n=30)
    rng = np.random.default_rng(0)
    when, ods = np.sort(rng.integers(0, 14000, 60)), rng.integers(0, 30, (60, 2))
    reqs = [
        (f"r{i}", float(t), int(o), int(dd))
        for i, (t, (o, dd)) in enumerate(zip(when, ods, strict=True))
        if o != dd
    ]
    tasks = poi_tasks(np.arange(30), 5, T0, 4 * 3600, np.random.default_rng(1))

    def run(seed: int):
        return simulate(city, demand(reqs), tasks, SimConfig(2, 2, 5, seed=seed), LocalDispatcher(city))

    a, b, c = run(1), run(1), run(2)
    assert [(r.id, r.matched_at_s, r.taxi_id) for r in a.riders] == [
        (r.id, r.matched_at_s, r.taxi_id) for r in b.riders
    ]
    ka, kb = run_kpis(city, a).scalars(), run_kpis(city, b).scalars()
    ka.pop("solve_ms_median"), kb.pop("solve_ms_median")  # wall time, the only thing that may differ
    assert ka == kb
    assert [r.taxi_id for r in a.riders] != [r.taxi_id for r in c.riders] or a.epochs != c.epochs


def test_requests_after_the_last_epoch_are_not_posted() -> None:
    city = line_city()
    d = demand([("early", 0, 0, 4), ("late", 4 * 3600 - 100, 0, 4)])
    trace = simulate(city, d, [], SimConfig(0, 1, 0, drift=False), LocalDispatcher(city), start_nodes=[0])
    assert [r.id for r in trace.riders] == ["early"] and trace.n_unposted == 1


def test_poi_tasks_are_distinct_sorted_and_inside_the_horizon() -> None:
    tasks = poi_tasks(np.array([5, 5, 6, 7, 8]), 4, T0, 3600.0, np.random.default_rng(3))
    assert len({t.node for t in tasks}) == 4
    times = [t.scheduled_at_s for t in tasks]
    assert times == sorted(times) and all(T0 <= x < T0 + 3600 and x == int(x) for x in times)
    with pytest.raises(ValueError, match="distinct POI nodes"):
        poi_tasks(np.array([1, 1, 2]), 3, T0, 3600.0, np.random.default_rng(0))


def test_design_kpi_formula() -> None:
    assert design_kpi(12.0, 3, 4.0, 0.0) == 1.0
    assert design_kpi(12.0, 3, 4.0, 2.0) == 3.0  # (12 + 2 * 3 * 4) / 12
    assert np.isnan(design_kpi(12.0, 0, 4.0, 0.0))


def test_drift_walks_the_fastest_path_toward_the_hub_within_the_budget() -> None:
    city = line_city(n=30, spacing_m=100.0)  # 2.9 km: cells 0, 1, 2 along x
    dm = DriftMap(city, 3000.0)
    assert list(dm.cells) == [0, 1, 2]
    hub2 = dm.hub_of_cell[2]
    assert int(dm.hubs[hub2]) == 25  # the node nearest the centre of cell 2 (x = 2500 m)
    node, used = dm.walk(hub2, 0, 95.0)  # 9 edges of 10 s fit in 95 s
    assert (node, used) == (9, pytest.approx(90.0))
    node, used = dm.walk(hub2, 0, 10_000.0)
    assert (node, used) == (25, pytest.approx(250.0))
    density = np.zeros(3)
    assert dm.choose_target(0, density, np.random.default_rng(0)) == -1
    density[2] = 5.0
    assert dm.choose_target(0, density, np.random.default_rng(0)) == hub2
    # cell 2 is 2 km away
    assert DriftMap(city, 1500.0).choose_target(0, density, np.random.default_rng(0)) == -1


def test_idle_taxi_drifts_toward_recent_demand() -> None:
    city = line_city(n=30, spacing_m=100.0)
    # two riders far east, beyond the radius of the taxi at node 0, make cell 2 the only dense cell
    d = demand([("x", 0, 29, 28), ("y", 0, 28, 29)])
    rec = Recording(LocalDispatcher(city))
    simulate(city, d, [], SimConfig(0, 1, 0, drift=True), rec, start_nodes=[0])
    nodes = [s.taxis[0].node for s in rec.snapshots[:4]]
    assert nodes[0] == 0 and nodes[1] > 0  # it moved east after the first epoch
