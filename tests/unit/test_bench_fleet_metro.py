"""The metropolitan fleet benchmark (``bench/bench_fleet_metro.py``): its schedule arithmetic by hand, and a
smoke run end to end on a small generated city (no timing asserted: only that its figures are consistent)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench import bench_fleet_metro as bfm
from bench import metro


def test_longest_first_schedule_by_hand() -> None:
    """Runs of 30, 20, 20, 10 s: one process ends at 80 s; two start 30 and 20, the second 20 goes to the
    process free at 20 (ends 40), the 10 to the one free at 30 (ends 40); opening the bundle delays both.
    Opening in 5 s, three processes end at 35 (5 + 30; 5 + 20 + 10; 5 + 20)."""
    runs = [20.0, 10.0, 30.0, 20.0]
    assert bfm.schedule_s(runs, 1, 0.0) == 80.0
    assert bfm.schedule_s(runs, 2, 0.0) == 40.0
    assert bfm.schedule_s(runs, 2, 5.0) == 45.0
    assert bfm.schedule_s(runs, 4, 0.0) == 30.0
    assert bfm.processes_needed(runs, 0.0, lead_s=40.0) == 2
    assert bfm.schedule_s(runs, 3, 5.0) == 35.0
    assert bfm.processes_needed(runs, 5.0, lead_s=40.0) == 3
    assert bfm.processes_needed(runs, 0.0, lead_s=29.0) is None  # the 30 s run alone is longer


def test_the_platform_day_is_seeded_and_lies_on_the_horizon() -> None:
    setup = bfm.SMOKE
    city = metro.metro_city(scale=setup.scale)
    near = bfm.centres(city, setup)
    one = bfm.platform_day(city, near, setup, 0, "2026-11-02")
    again = bfm.platform_day(city, near, setup, 0, "2026-11-02")
    inst, ordinary = one.fleet.instrumented_nodes, one.fleet.ordinary_nodes
    assert inst is not None and ordinary is not None
    assert one.demand == again.demand
    assert np.array_equal(inst, np.asarray(again.fleet.instrumented_nodes))
    assert one.demand.requests != bfm.platform_day(city, near, setup, 1, "2026-11-02").demand.requests
    reqs = one.demand.requests
    start = city.horizon.start_s("2026-11-02")
    assert all(start <= r.time_s < start + city.horizon.length_s and r.origin != r.destination for r in reqs)
    assert [(r.time_s, r.id) for r in reqs] == sorted((r.time_s, r.id) for r in reqs)
    # the posted fleet starts where it stood; any other size takes those positions too (instrumented first)
    posted = one.starts(setup.n1, setup)
    assert sorted(posted[: setup.n1]) == sorted(inst.tolist())
    assert sorted(posted[setup.n1 :]) == sorted(ordinary.tolist())
    for x in setup.sizes:
        assert len(one.starts(x, setup)) == x + setup.n0
    tasks = bfm.platform_tasks(city, near, setup)
    assert len({t.node for t in tasks}) == len(tasks) == setup.n_tasks
    assert all(0.0 <= t.offset_s < city.horizon.length_s for t in tasks)


@pytest.mark.slow
def test_smoke_run_reports_consistent_figures(tmp_path: Path) -> None:
    assert bfm.main(["--smoke", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "perf_fleet_metro.json").read_text())
    setup = bfm.SMOKE
    days = res["engine"]["days"]
    assert len(days) == setup.days and res["engine"]["open_s"] > 0
    for d in days:  # the parts of a day add up to the day
        assert sum(d["spent_s"].values()) == pytest.approx(d["wall_s"])
        assert d["peak_mb"] >= res["engine"]["open_peak_mb"] > 0
    assert days[0]["trees_grown"] > 0 and res["engine"]["drift"]["held"] > 0
    runs = res["cluster"]["runs"]
    assert sorted((r["n1"], r["day"]) for r in runs) == [(x, 0) for x in setup.sizes]
    same = next(r for r in runs if r["n1"] == setup.n1)  # the engine's first day, run on the cluster
    assert same["matching_rate"] == days[0]["matching_rate"]
    assert all(r["cpu_s"] > 0 for r in runs)
    assert len(res["cluster"]["open"]) == len(res["cluster"]["peak_mb"]) == setup.workers
    for r in res["resolve"].values():
        assert r["runs"] == len(setup.sizes) * setup.m_days
        assert r["processes"] >= r["lower_bound"] >= 1
        assert r["makespan_s"] <= bfm.LEAD_S
    text = (tmp_path / "PERFORMANCE.md").read_text()
    assert "<!-- bench:fleet-metro -->" in text and "## Fleet sizing at metropolitan scale" in text
