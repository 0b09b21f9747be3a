"""The fleet-sizing worker's parts without simulation: schedule, the recorded history (requests and fleet by
local day, k of M days), the history window, the fleet of a solve, run cache and runner, settings and
options. (Real solves: tests/e2e/test_worker.py.)"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import logging
import math
from pathlib import Path
from typing import Any, get_args
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from pydantic import ValidationError

from app.adapters import MemoryStore
from app.adapters.city_registry import CityRegistry
from app.entrypoints.worker import parser, settings_from_args
from app.ports import EpochCommit, SolveRequest, local_day
from app.runs import (
    RunCache,
    RunJob,
    Runner,
    RunResult,
    RunSpec,
    TaskTemplate,
    open_bundle,
    simulate_spec,
    tasks_for,
)
from app.runs.workload import placed_tasks
from app.schemas.fleet import render_recommendation
from app.settings import (
    SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR,
    SUBSIDY_SWEEP_DEFAULT,
    DivergenceName,
    Settings,
)
from app.usecases.fleet_history import (
    FleetHistory,
    HistoryState,
    RecordedDemandError,
    RecordedFleet,
    SizingConfig,
    day_from_records,
    demand_from_records,
    posted_fleet,
    recorded_days,
    spread_sizes,
    start_nodes,
)
from app.usecases.fleet_solve import (
    FleetOrigin,
    FleetSolver,
    HistoryDay,
    HistoryWindow,
    NotReady,
    TaskSet,
    observed_today,
)
from app.worker.schedule import coming_interval, due_interval
from services.city import City, FleetParams, Horizon
from services.fleet.dro import DIVERGENCE_NAMES
from services.model import Task, TaskId
from services.network.graph import road_graph
from services.sim.demand import DemandSet, Request
from services.sim.engine import SimConfig, simulate
from services.sim.kpi import HourKpis, RunKpis, TaskOutcome
from services.sim.local import LocalDispatcher
from tests.api.fakes import CITY, build_bundle, node_id

SHANGHAI = ZoneInfo("Asia/Shanghai")


def at(day: int, hour: int, minute: int = 0, second: int = 0, month: int = 11) -> float:
    """POSIX time of a local Chengdu wall-clock time in 2026."""
    return dt.datetime(2026, month, day, hour, minute, second, tzinfo=SHANGHAI).timestamp()


@pytest.fixture(scope="module")
def tiny_cities(tmp_path_factory: pytest.TempPathFactory) -> CityRegistry:
    """A registry serving the API tests' 5 x 5 lattice city."""
    root = build_bundle(tmp_path_factory.mktemp("cities"))
    return CityRegistry(bundled_dir=tmp_path_factory.mktemp("none"), user_dir=root)


@pytest.fixture(scope="module")
def tiny(tiny_cities: CityRegistry) -> City:
    """The API tests' 5 x 5 lattice city (Asia/Shanghai, horizon 08:00-12:00)."""
    return tiny_cities.get(CITY)


# ----------------------------------------------------------------------------------------------- schedule


@pytest.mark.parametrize(
    ("now", "coming", "due"),
    [
        ((23, 6, 59, 59), (23, 8), None),  # 3601 s ahead: not yet
        ((23, 7, 0, 0), (23, 8), (23, 8)),
        ((23, 7, 59, 59), (23, 8), (23, 8)),
        ((23, 8, 0, 0), (23, 9), (23, 9)),  # an hour that starts now is not "coming"
        ((23, 10, 30, 0), (23, 11), (23, 11)),
        ((23, 11, 0, 0), (24, 8), None),  # the horizon ends at 12:00: next is tomorrow 08:00
        ((23, 23, 30, 0), (24, 8), None),
        ((30, 11, 15, 0), (1, 8), None),  # across a month end (the 1st is in December)
    ],
)
def test_coming_and_due_hours(
    now: tuple[int, int, int, int], coming: tuple[int, int], due: tuple[int, int] | None
) -> None:
    hz = Horizon()  # Asia/Shanghai, 4 hours from 08:00
    t = at(*now)
    month = 12 if coming[0] == 1 else 11
    k = coming_interval(hz, t)
    assert hz.interval_start_s(k) == at(coming[0], coming[1], month=month)
    assert hz.in_horizon(k)
    d = due_interval(hz, t, 3600.0)
    assert (d is None) == (due is None) and (d is None or d == k)


def test_due_in_another_time_zone_and_lead() -> None:
    hz = Horizon(timezone="America/New_York")
    t = dt.datetime(2026, 7, 1, 6, 30, tzinfo=ZoneInfo("America/New_York")).timestamp()
    k = coming_interval(hz, t)
    assert hz.label(k) == "2026-07-01T08:00"
    assert due_interval(hz, t, 3600.0) is None and due_interval(hz, t, 5400.0) == k


# ------------------------------------------------------------------------------------------ recorded history


def record(
    epoch: str,
    time_s: float,
    riders: list[tuple[str, int, int, float]],
    fleet: tuple[int, int] | None = None,
    at_open: tuple[list[Any], list[Any]] | None = None,
) -> str:
    """An epoch's record as the service writes it (``app.usecases.epochs``)."""
    doc: dict[str, Any] = {
        "epoch_id": epoch,
        "time": dt.datetime.fromtimestamp(time_s, tz=SHANGHAI).isoformat(),
        "time_s": time_s,
        "riders": [
            {"id": i, "origin": o, "destination": d, "requested_at": "", "requested_at_s": t}
            for i, o, d, t in riders
        ],
    }
    if fleet is not None:
        doc["fleet"] = {"instrumented": fleet[0], "ordinary": fleet[1]}
    if at_open is not None:
        doc["fleet_at_open"] = {"instrumented": at_open[0], "ordinary": at_open[1]}
    return json.dumps(doc)


def test_recorded_epochs_become_a_demand_set(tiny: City) -> None:
    t0 = at(23, 8)
    a = ("a", node_id(0, 0), node_id(4, 4), t0 + 10.7)
    records = [
        record("e1", t0 + 200, [a, ("b", node_id(1, 0), node_id(2, 3), t0 + 150)]),
        # a waits: recorded again (here even with a later time: the first one seen is kept)
        record(
            "e2",
            t0 + 400,
            [
                (a[0], a[1], a[2], t0 + 50),
                ("c", node_id(3, 3), node_id(0, 1), t0 + 390),
                ("x", 999_999, node_id(0, 1), t0 + 399),
            ],
        ),
        record("e3", t0 + 600, [("p", node_id(2, 2), node_id(1, 1), at(22, 23, 59))]),  # the day before
    ]
    ds = demand_from_records(tiny, "2026-11-23", records)
    assert isinstance(ds, DemandSet) and ds.city == CITY and ds.date == "2026-11-23"
    assert ds.generator == "recorded" and ds.seed is None
    assert [r.id for r in ds.requests] == ["a", "b", "c"]
    assert [r.time_s for r in ds.requests] == [t0 + 10, t0 + 150, t0 + 390]
    ids = tiny.network.node_ids
    assert [(int(ids[r.origin]), int(ids[r.destination])) for r in ds.requests] == [
        (node_id(0, 0), node_id(4, 4)),
        (node_id(1, 0), node_id(2, 3)),
        (node_id(3, 3), node_id(0, 1)),
    ]
    assert ds.params == {"epochs": 3, "rider_rows": 6, "unknown_nodes": 1}
    net = tiny.network
    p = Request(
        "p", float(math.floor(at(22, 23, 59))), net.index_of(node_id(2, 2)), net.index_of(node_id(1, 1))
    )
    assert demand_from_records(tiny, "2026-11-22", records).requests == (p,)


def test_a_days_fleet_is_where_its_opening_epoch_found_it(tiny: City) -> None:
    """The fleet of a day: the counts and positions of the epoch that opened its horizon (the earliest
    such record), node ids as network indices, unknown ids left out; without one, the largest counts any
    epoch posted and no positions."""
    t0 = at(23, 8)
    net = tiny.network
    opening = record("e1", t0, [], (2, 1), ([node_id(1, 1), node_id(2, 2)], [node_id(4, 4), 999_999]))
    later = record("e2", t0 + 200, [], (3, 4))
    day = day_from_records(tiny, "2026-11-23", [later, opening])
    assert day.fleet is not None and (day.fleet.instrumented, day.fleet.ordinary) == (2, 1)
    assert day.fleet.instrumented_nodes is not None and day.fleet.ordinary_nodes is not None
    assert day.fleet.instrumented_nodes.tolist() == [net.index_of(node_id(1, 1)), net.index_of(node_id(2, 2))]
    assert day.fleet.ordinary_nodes.tolist() == [net.index_of(node_id(4, 4))]
    no_open = day_from_records(tiny, "2026-11-23", [later, record("e3", t0 + 400, [], (5, 2))])
    assert no_open.fleet is not None and (no_open.fleet.instrumented, no_open.fleet.ordinary) == (5, 4)
    assert no_open.fleet.instrumented_nodes is None
    assert posted_fleet([day, no_open, no_open]) == (5, 4)  # medians of (2, 5, 5) and (1, 4, 4)
    assert posted_fleet([day, no_open]) == (4, 3)  # 3.5 and 2.5 rounded half up
    bare = day_from_records(tiny, "2026-11-23", [record("e9", t0, [])])  # records without a fleet
    assert bare.fleet is None and posted_fleet([bare]) is None and posted_fleet([bare, day]) == (2, 1)
    with pytest.raises(RecordedDemandError, match="bad node id"):
        day_from_records(tiny, "2026-11-23", [record("e1", t0, [], (1, 0), (["x"], []))])


@pytest.mark.parametrize(
    "bad",
    [
        "not json",
        '{"epoch_id": "e1"}',
        '{"epoch_id": "e1", "riders": [{"id": "a"}]}',
        '{"riders": 3}',
        '{"epoch_id": "e1", "riders": [], "fleet": {"instrumented": "many"}}',
    ],
)
def test_malformed_records_are_an_error(tiny: City, bad: str) -> None:
    with pytest.raises(RecordedDemandError, match="2026-11-23"):
        demand_from_records(tiny, "2026-11-23", [bad])


def test_simulated_taxis_start_where_the_recorded_fleet_stood() -> None:
    """Each kind takes its own recorded positions: all of them (in a seeded order) up to the number posted,
    then seeded draws among them; a kind with none takes the other kind's; no positions: seeded nodes."""
    inst, ordinary = np.array([10, 11, 12]), np.array([20, 21])
    fleet = RecordedFleet(3, 2, inst, ordinary)
    day = dt.date(2026, 11, 23)
    few = start_nodes(fleet, day, 2, 1, seed=0)
    assert few is not None and few.size == 3
    assert len(set(few[:2].tolist())) == 2 and set(few[:2].tolist()) <= {10, 11, 12} and few[2] in (20, 21)
    many = start_nodes(fleet, day, 5, 4, seed=0)
    assert many is not None and many.size == 9
    assert {10, 11, 12} <= set(many[:5].tolist()) <= {10, 11, 12}
    assert {20, 21} <= set(many[5:].tolist()) <= {20, 21}
    again = start_nodes(fleet, day, 5, 4, seed=0)
    assert again is not None and np.array_equal(many, again)  # seeded
    only_ordinary = RecordedFleet(0, 2, np.zeros(0, dtype=np.int64), ordinary)
    mixed = start_nodes(only_ordinary, day, 3, 2, seed=1)
    assert mixed is not None and set(mixed.tolist()) <= {20, 21}
    assert start_nodes(RecordedFleet(3, 2), day, 2, 1, seed=0) is None


def test_candidate_sizes_spread_around_the_instrumented_fleet() -> None:
    assert spread_sizes(150) == (38, 75, 113, 150, 225, 300)
    assert spread_sizes(4) == (1, 2, 3, 4, 6, 8)
    assert spread_sizes(1) == (1, 2)
    with pytest.raises(ValueError, match="no instrumented fleet"):
        spread_sizes(0)


def commit_records(store: MemoryStore, city: City, docs: list[tuple[float, str]]) -> None:
    """Commit one epoch per (time, record), kept under the city's local day as the API does."""
    for i, (time_s, doc) in enumerate(docs):
        version = store.load_state(city.name, [], []).version
        day = local_day(time_s, city.horizon.timezone)
        commit = EpochCommit(
            f"e{time_s:.0f}", "h", time_s, version, (), (), "{}", demand_json=doc, demand_day=day
        )
        assert store.commit_epoch(city.name, commit).status == "committed", i


def test_records_are_kept_by_the_citys_local_day(tiny: City) -> None:
    store = MemoryStore()
    r1 = ("r1", node_id(0, 0), node_id(1, 1), at(23, 1))  # UTC 22 Nov 17:00
    r2 = ("r2", node_id(1, 1), node_id(2, 2), at(23, 9))  # UTC 23 Nov 01:00
    r3 = ("r3", node_id(2, 2), node_id(3, 3), at(24, 1))  # UTC 23 Nov 17:00, local 24 Nov
    commit_records(store, tiny, [(r[3] + 60, record(r[0], r[3] + 60, [r])) for r in (r1, r2, r3)])
    history = FleetHistory(store, SizingConfig())
    assert len(history.recorded_day(tiny, dt.date(2026, 11, 23))) == 2
    assert history.recorded_epoch_counts(tiny, [dt.date(2026, 11, d) for d in (22, 23, 24)]) == [0, 2, 1]
    found = recorded_days(history, tiny, dt.date(2026, 11, 25), want=5, lookback_days=4)
    assert [(d.date.isoformat(), [r.id for r in d.demand.requests]) for d in found] == [
        ("2026-11-24", ["r3"]),
        ("2026-11-23", ["r1", "r2"]),
    ]
    assert [d.date.day for d in recorded_days(history, tiny, dt.date(2026, 11, 25), 1, 4)] == [24]
    assert [d.date for d in recorded_days(history, tiny, dt.date(2026, 11, 25), 5, 1)] == [found[0].date]


def test_the_history_counts_days_with_epochs_and_dates_the_first_solve(tiny: City) -> None:
    store = MemoryStore()
    commit_records(store, tiny, [(at(day, 9), record(f"d{day}", at(day, 9), [])) for day in (20, 21, 23)])
    history = FleetHistory(store, SizingConfig(days=5, lookback_days=7))
    state = history.state(tiny, dt.date(2026, 11, 23))  # the 23rd itself does not count today
    assert (state.days, state.needed, state.enough) == (2, 5, False)
    assert state.first_solve_on == dt.date(2026, 11, 26)  # the 23rd, 24th and 25th still to record
    assert state.describe().startswith("collecting history: 2 of 5 days")
    assert "2026-11-26" in state.describe()
    later = history.state(tiny, dt.date(2026, 11, 24))
    assert (later.days, later.first_solve_on) == (3, dt.date(2026, 11, 26))
    own = dataclasses.replace(tiny, fleet=FleetParams(days=2))
    assert history.state(own, dt.date(2026, 11, 24)).enough  # the city's own M
    assert HistoryState(dt.date(2026, 11, 24), 3, 3, 7).describe().startswith("history complete")


def solver(
    store: MemoryStore, tmp_path: Path, config: SizingConfig, cities: CityRegistry | None = None
) -> FleetSolver:
    """A fleet solve over ``store`` whose runs would go to an empty cache (these tests start none)."""
    return FleetSolver(
        store,
        Runner(RunCache(tmp_path)),
        config,
        render=render_recommendation,
        cities=cities or CityRegistry(),
    )


def test_the_window_is_recorded_with_m_days_else_synthetic_on_a_demo_city(tiny: City, tmp_path: Path) -> None:
    store = MemoryStore()
    docs = []
    for day in (20, 21, 22):
        t = at(day, 9)
        docs.append((t, record(f"d{day}", t, [(f"r{day}", node_id(0, 0), node_id(4, 4), t - 30)])))
    commit_records(store, tiny, docs)
    k = tiny.horizon.interval_of(at(23, 9))
    cfg = SizingConfig(days=2, lookback_days=7)
    two = solver(store, tmp_path, cfg).window(tiny, k, cfg)
    assert two.source == "recorded" and two.recorded_available == 2
    assert [d.label for d in two.days] == ["2026-11-22", "2026-11-21"]
    assert [d.spec_day for d in two.days] == [
        dt.date(2026, 11, 22).toordinal(),
        dt.date(2026, 11, 21).toordinal(),
    ]
    assert all(d.demand is not None and len(d.demand.requests) == 1 for d in two.days)
    four = SizingConfig(days=4, lookback_days=7, seed=5)
    with pytest.raises(NotReady, match="collecting history: 3 of 4 days") as waiting:
        solver(store, tmp_path, four).window(tiny, k, four)
    assert waiting.value.kind == "insufficient_history"
    demo = dataclasses.replace(tiny, fleet=FleetParams(synthetic_history=True))
    synthetic = solver(store, tmp_path, four).window(demo, k, four)
    assert synthetic.source == "synthetic" and synthetic.recorded_available == 3
    assert [(d.label, d.spec_day, d.demand) for d in synthetic.days] == [
        (f"synthetic-{d}", d, None) for d in range(1, 5)
    ]
    assert "3 day(s) with epochs" in synthetic.note and "seed 5" in synthetic.note
    # the look-back bounds the search (retention): one day back finds only the 22nd
    short = SizingConfig(days=2, lookback_days=1)
    with pytest.raises(NotReady, match="1 of 2 days"):
        solver(store, tmp_path, short).window(tiny, k, short)


def test_the_fleet_comes_from_the_city_else_the_fleet_posted_else_the_settings(
    tiny: City, tiny_cities: CityRegistry, tmp_path: Path
) -> None:
    store = MemoryStore()
    docs = []
    for day, (n1, n0) in zip((20, 21, 22), ((150, 450), (160, 440), (140, 460)), strict=True):
        t = at(day, 8)
        docs.append((t, record(f"d{day}", t, [], (n1, n0), ([node_id(0, 0)] * n1, [node_id(1, 1)] * n0))))
    commit_records(store, tiny, docs)
    k = tiny.horizon.interval_of(at(23, 9))
    cfg = SizingConfig(sizes=(10, 20), n0=60, days=3, lookback_days=7)
    sizing = solver(store, tmp_path, cfg, tiny_cities)
    window = sizing.window(tiny, k, cfg)
    derived, origin = sizing.fleet_config(tiny, window, cfg)
    assert derived.sizes == spread_sizes(150) and derived.n0 == 450
    assert origin == FleetOrigin("recorded", "recorded", 150, 450, "recorded")
    own = dataclasses.replace(tiny, fleet=FleetParams(sizes=(100, 300), n0=400))
    mine, from_city = sizing.fleet_config(own, window, cfg.for_city(own.fleet))
    assert mine.sizes == (100, 300) and mine.n0 == 400
    assert (from_city.sizes, from_city.n0, from_city.posted_instrumented) == ("city", "city", 150)
    synthetic = HistoryWindow("synthetic", (HistoryDay("synthetic-1", 1, None),), 0, "")
    fallback, from_settings = sizing.fleet_config(tiny, synthetic, cfg)
    assert fallback.sizes == (10, 20) and fallback.n0 == 60
    assert from_settings == FleetOrigin("settings", "settings", None, None, "seeded")
    jobs = sizing.jobs(tiny, window, derived, TaskSet("registered", (TaskTemplate("a", 3, 0.0),)))
    assert len(jobs) == 6 * 3
    job = jobs[(derived.sizes[0], 0)]
    assert job.start_nodes is not None and len(job.start_nodes) == derived.sizes[0] + 450
    net = tiny.network
    assert set(job.start_nodes[: derived.sizes[0]]) == {net.index_of(node_id(0, 0))}
    assert set(job.start_nodes[derived.sizes[0] :]) == {net.index_of(node_id(1, 1))}


def test_registered_tasks_of_the_day_become_templates_else_a_demo_citys_seeded_set(
    tiny: City, tiny_cities: CityRegistry, tmp_path: Path
) -> None:
    """The platform's tasks scheduled within the target day's horizon are every simulated day's tasks, kept
    at their offset from the horizon's start; without any, one seeded set on a demo city (or one per day
    if they vary), and no solve on any other city."""
    store = MemoryStore()
    k = tiny.horizon.interval_of(at(23, 9))
    cfg = SizingConfig(sizes=(2, 4), days=2)
    sizing = solver(store, tmp_path, cfg, tiny_cities)
    demo = dataclasses.replace(tiny, fleet=FleetParams(synthetic_history=True))
    assert sizing.task_set(demo, k, cfg) == TaskSet("synthetic", None)
    varying = dataclasses.replace(cfg, vary_tasks=True)
    assert sizing.task_set(demo, k, varying).source == "synthetic_per_day"
    with pytest.raises(NotReady, match="no monitoring task") as waiting:
        sizing.task_set(tiny, k, cfg)
    assert waiting.value.kind == "no_tasks"
    store.put_tasks(
        CITY,
        [
            Task(TaskId("b"), 3, at(23, 10, 30)),
            Task(TaskId("a"), 7, at(23, 8, 5)),
            Task(TaskId("yesterday"), 1, at(22, 9)),
            Task(TaskId("after-hours"), 1, at(23, 12, 0)),
        ],
    )
    ts = sizing.task_set(tiny, k, cfg)
    assert ts.source == "registered"
    assert ts.templates == (TaskTemplate("a", 7, 300.0), TaskTemplate("b", 3, 9000.0))
    window = sizing.window(demo, k, cfg)
    jobs = sizing.jobs(tiny, window, cfg, ts)
    assert {j.spec.n_tasks for j in jobs.values()} == {2} and all(
        j.tasks == ts.templates for j in jobs.values()
    )
    assert all(j.start_nodes is None for j in jobs.values())  # synthetic days: seeded starts
    seeded = sizing.jobs(tiny, window, cfg, TaskSet("synthetic", None))
    assert {j.spec.tasks_day for j in seeded.values()} == {0}
    per_day = sizing.jobs(tiny, window, varying, TaskSet("synthetic_per_day", None))
    assert {j.spec.tasks_day for j in per_day.values()} == {None}


def test_observed_hours_are_the_whole_horizon_hours_past(tiny: City) -> None:
    """Solving 11:00 at 10:05 sees 08:00 and 09:00 (10:00 is not over); solving 09:00 at 08:00 sees none."""
    store = MemoryStore()
    riders = [
        ("r1", node_id(0, 0), node_id(1, 1), at(23, 8, 10)),
        ("r2", node_id(1, 1), node_id(2, 2), at(23, 8, 50)),
        ("r3", node_id(2, 2), node_id(3, 3), at(23, 9, 20)),
        ("r4", node_id(2, 2), node_id(3, 3), at(23, 10, 1)),
    ]
    commit_records(store, tiny, [(r[3] + 5, record(r[0], r[3] + 5, [r])) for r in riders])
    history = FleetHistory(store, SizingConfig())
    k11 = tiny.horizon.interval_of(at(23, 11))
    seen = observed_today(history, tiny, k11, at(23, 10, 5))
    assert seen.date == "2026-11-23" and seen.requests_per_hour == (2, 1)
    assert observed_today(history, tiny, k11, at(23, 11, 30)).requests_per_hour == (2, 1, 1)
    k9 = tiny.horizon.interval_of(at(23, 9))
    assert observed_today(history, tiny, k9, at(23, 8)).requests_per_hour == ()
    assert observed_today(history, tiny, k9, at(23, 11)).requests_per_hour == (2,)  # never the hour itself


def test_tasks_day_fixes_the_task_draw_across_days(tiny_cities: CityRegistry) -> None:
    bundle = open_bundle(tiny_cities.bundle_dir(CITY))
    spec = RunSpec(city=CITY, n_tasks=5, day=1, tasks_day=0)
    one = tasks_for(spec, bundle, "2026-11-23")
    other = tasks_for(dataclasses.replace(spec, day=2), bundle, "2026-11-24")
    start = bundle.city.horizon.start_s
    assert [(t.node, t.scheduled_at_s - start("2026-11-23")) for t in one] == [
        (t.node, t.scheduled_at_s - start("2026-11-24")) for t in other
    ]
    own = [tasks_for(RunSpec(city=CITY, n_tasks=5, day=d), bundle, "2026-11-23") for d in (1, 2, 3)]
    assert len({tuple((t.node, t.scheduled_at_s) for t in ts) for ts in own}) > 1  # per day they vary
    placed = placed_tasks([TaskTemplate("a", 3, 60.0)], bundle, "2026-11-24")
    assert placed == [Task(TaskId("a"), 3, start("2026-11-24") + 60.0)]


def test_runs_of_a_process_share_the_city_and_its_search_structures(tiny_cities: CityRegistry) -> None:
    """Runs with Step 3 off simulate one city object per process (its graph, landmarks and drift trees are
    kept per city object), and a passive run equals the same run on a freshly made passive city."""
    bundle = open_bundle(tiny_cities.bundle_dir(CITY))
    passive = bundle.city_for(False)
    assert passive is bundle.city_for(False) and bundle.city_for(True) is bundle.city
    assert passive.params.active_sensing is False and passive.network is bundle.city.network
    n = bundle.city.network.n_nodes
    start = bundle.city.horizon.start_s("2026-11-23")
    reqs = tuple(Request(f"r{i}", start + 300.0 * i, (7 * i) % n, (7 * i + 5) % n) for i in range(30))
    demand = DemandSet(CITY, "2026-11-23", reqs, "hand")
    spec = RunSpec(city=CITY, n1=3, n0=3, n_tasks=4, active=False)
    city_a, one = simulate_spec(spec, bundle, demand)
    graphs = road_graph.cache_info().currsize
    city_b, _ = simulate_spec(dataclasses.replace(spec, seed=1), bundle, demand)
    assert city_a is city_b is passive and road_graph.cache_info().currsize == graphs
    fresh = dataclasses.replace(
        bundle.city, params=dataclasses.replace(bundle.city.params, active_sensing=False)
    )
    tasks = tasks_for(spec, bundle, demand.date)
    again = simulate(fresh, demand, tasks, SimConfig(3, 3, 4, seed=0), LocalDispatcher(fresh))
    assert again.riders == one.riders and again.assignments == one.assignments == ()
    assert sum(r.matched_at_s is not None for r in one.riders) > 0


# -------------------------------------------------------------------------------------------- runs, cache


BUNDLE = Path("/bundles/chengdu")  # jobs name their bundle; these tests never open it


def result(key: str, size: int, kpi: float = 2.5) -> RunResult:
    hours = tuple(
        HourKpis(h, 30, 25, 25 / 30, 120.0, 0.4, 0.01, cost, hk, 2)
        for h, (hk, cost) in enumerate(zip((0.0, 1.5, kpi, 3.0), (0.0, 3.0, 5.0, 6.0), strict=True))
    )
    task = TaskOutcome("t1", 7, 1.0e9, None, None, None, None)
    kpis = RunKpis(
        120, 100, 60, 40, 100 / 120, 200.0, 90.0, 20000.0, 3, 20, 0.02, 0.4, 1, 0, 0, 0, float("nan"),
        float("nan"), 12.5, 18.75, kpi, 4.0, hours, (task,),
    )  # fmt: skip
    spec = RunSpec(n1=size, day=1)
    return RunResult(key, spec, {"date": "2026-11-23", "seed": 1}, kpis, 20, 0.2)


def test_cache_round_trip_and_unreadable_files(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    cache = RunCache(tmp_path / "runs")
    assert cache.get("k") is None
    r = result("k", 20)
    cache.put(r)
    back = cache.get("k")
    assert back is not None and math.isnan(back.kpis.completion_rate) and math.isnan(back.kpis.mean_delay_s)
    assert back.to_json() == r.to_json() and back.kpis.hours == r.kpis.hours
    assert back.kpis.tasks == r.kpis.tasks and back.spec == r.spec and back.n_requests == 140
    assert back.cpu_s is None
    timed = dataclasses.replace(r, key="t", cpu_s=0.125)
    cache.put(timed)
    back = cache.get("t")
    assert back is not None and back.cpu_s == 0.125 and back.to_json() == timed.to_json()
    (tmp_path / "runs" / "bad.json").write_text("{truncated")
    with caplog.at_level(logging.WARNING):
        assert cache.get("bad") is None
    assert "unreadable cached run" in caplog.text


def test_job_keys_name_the_inputs() -> None:
    spec = RunSpec(city="chengdu", n1=20, day=3)
    d1 = DemandSet("chengdu", "2026-11-23", (Request("a", 1.0e9, 1, 2),), "recorded")
    d2 = DemandSet("chengdu", "2026-11-23", (Request("a", 1.0e9, 1, 3),), "recorded")
    keys = {
        RunJob(spec, BUNDLE).key,
        RunJob(spec, BUNDLE, d1).key,
        RunJob(spec, BUNDLE, d2).key,
        RunJob(RunSpec(n1=30, day=3), BUNDLE).key,
    }
    keys |= {RunJob(dataclasses.replace(spec, tasks_day=0), BUNDLE).key}
    keys |= {RunJob(spec, BUNDLE, None, (TaskTemplate("a", 1, 0.0),)).key}
    keys |= {RunJob(spec, BUNDLE, None, (TaskTemplate("a", 1, 60.0),)).key}
    keys |= {RunJob(spec, BUNDLE, start_nodes=(1, 2)).key, RunJob(spec, BUNDLE, start_nodes=(2, 1)).key}
    assert len(keys) == 9
    same = DemandSet("chengdu", "2026-11-23", d1.requests, "x")
    assert RunJob(spec, BUNDLE, d1).key == RunJob(spec, BUNDLE, same).key


def test_runner_uses_the_cache_and_reports_failures_without_caching_them(tmp_path: Path) -> None:
    calls: list[int] = []

    def fake(job: RunJob) -> RunResult:
        calls.append(job.spec.n1)
        if job.spec.n1 == 30:
            raise ValueError("no taxis left")
        return result(job.key, job.spec.n1, kpi=job.spec.n1 / 10)

    runner = Runner(RunCache(tmp_path), run_fn=fake)
    jobs = [RunJob(RunSpec(n1=x, day=1), BUNDLE) for x in (10, 20, 30)]
    seen: list[tuple[int, int, int, int, int, int]] = []
    batch = runner.run(
        [*jobs, jobs[0]], lambda p: seen.append((p.total, p.done, p.cached, p.failed, p.running, p.queued))
    )
    assert sorted(calls) == [10, 20, 30] and batch.cached == 0
    assert set(batch.results) == {jobs[0].key, jobs[1].key}
    assert batch.failures == {jobs[2].key: "ValueError: no taxis left"}
    # a repeated job runs once; one at a time in this process, the costliest (N1 = 30) first
    assert seen == [
        (3, 0, 0, 0, 0, 3),
        (3, 0, 0, 0, 1, 2),
        (3, 1, 0, 1, 0, 2),
        (3, 1, 0, 1, 1, 1),
        (3, 2, 0, 1, 0, 1),
        (3, 2, 0, 1, 1, 0),
        (3, 3, 0, 1, 0, 0),
    ]
    again = runner.run(jobs)
    assert sorted(calls) == [10, 20, 30, 30] and again.cached == 2
    assert again.results[jobs[1].key].kpis.design_kpi == 2.0


# ------------------------------------------------------------------------------------- settings, options


def test_divergence_names_match_the_engine() -> None:
    assert set(get_args(DivergenceName)) == set(DIVERGENCE_NAMES)


def test_settings_and_config() -> None:
    s = Settings().with_values(
        worker_sizes=[40, 20], worker_days=3, worker_divergence="burg", retention_s=3 * 86400
    )
    cfg = SizingConfig.from_settings(s.sizing, s.store.retention_s)
    assert cfg.sizes == (20, 40) and cfg.days == 3 and cfg.ambiguity.divergence == "burg"
    assert cfg.lookback_days == 4 and cfg.completion_target is None
    assert cfg.subsidy_cny_per_vehicle_hour == SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR > 0.0
    assert cfg.subsidy_sweep == SUBSIDY_SWEEP_DEFAULT and cfg.rolling_days == 7 and not cfg.vary_tasks
    assert Settings().with_values(worker_subsidy_sweep=[2.0, 0.5, 2.0]).sizing.subsidy_sweep == [0.5, 2.0]
    assert Settings().with_values(tokens={"abcdefgh12": ["admin"]}).auth.tokens == {"abcdefgh12": ["admin"]}
    bad_settings: list[dict[str, Any]] = [
        {"worker_sizes": [10, 10]},
        {"worker_sizes": [0]},
        {"worker_days": 1},
        {"worker_alpha": 1.0},
        {"worker_subsidy_sweep": [-1.0]},
        {"worker_subsidy_sweep": [float("inf")]},
        {"worker_heartbeat_s": 30.0, "worker_stale_s": 30.0},
        {"worker_nice": 20},
        {"worker_embedded": "yes"},
    ]
    for bad in bad_settings:
        with pytest.raises(ValidationError):
            Settings(**bad)
    with pytest.raises(ValueError, match="days"):
        SizingConfig(days=1)


def test_the_service_embeds_the_worker_on_the_memory_store_unless_told() -> None:
    assert Settings().embeds_worker() and not Settings().with_values(store="redis").embeds_worker()
    assert Settings().with_values(store="redis", worker_embedded="on").embeds_worker()
    assert not Settings().with_values(worker_embedded="off").embeds_worker()


def test_an_embedded_worker_with_an_unknown_city_does_not_start(
    tiny_cities: CityRegistry, caplog: pytest.LogCaptureFixture
) -> None:
    from app.bootstrap import embedded_worker

    with caplog.at_level(logging.ERROR):
        worker = embedded_worker(
            Settings().with_values(worker_cities=[CITY, "atlantis"]), MemoryStore(), tiny_cities
        )
    assert worker is None
    assert "unknown cities ['atlantis'] in SD_WORKER_CITIES; served: ['tiny']" in caplog.text


def test_options_override_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SD_WORKER_DAYS", "7")
    monkeypatch.setenv("SD_WORKER_JOBS", "3")
    options = [
        "--sizes",
        "4,2",
        "--target",
        "0.9",
        "--subsidy",
        "0.5",
        "--city",
        "chengdu",
        "--divergence",
        "chi2",
        "--jobs",
        "1",
    ]
    args = parser().parse_args(options)
    s = settings_from_args(args)
    assert s.sizing.sizes == [2, 4] and s.sizing.completion_target == 0.9 and s.worker.cities == ["chengdu"]
    assert s.sizing.subsidy_cny_per_vehicle_hour == 0.5
    assert s.sizing.divergence == "chi2" and s.runs.jobs == 1 and s.sizing.days == 7
    assert settings_from_args(parser().parse_args([])).sizing.completion_target is None
    assert settings_from_args(parser().parse_args(["--target", "off"])).sizing.completion_target is None
    with pytest.raises(SystemExit):
        parser().parse_args(["--sizes", "two"])
    with pytest.raises(ValidationError):
        settings_from_args(parser().parse_args(["--alpha", "2"]))


class _NoRuns:
    """A runner that must not be asked for anything."""

    workers = 2

    def run(self, jobs: Any, progress: Any = None) -> Any:
        raise AssertionError(f"{len(jobs)} runs started for a city that cannot be sized")

    def call(self, fn: Any, item: Any) -> Any:
        raise AssertionError("a plan was asked for a city that cannot be sized")


def test_a_city_without_its_history_starts_no_run_and_is_reported_once(
    tiny_cities: CityRegistry, caplog: pytest.LogCaptureFixture
) -> None:
    """The worker's scheduled solves of an imported city with too little history: no run (no process, no
    network loaded), the reason in the heartbeat and the log once, nothing in the history; an admin
    request gets one failed entry with its reason."""
    from app.worker.heartbeat import WorkerStatus
    from app.worker.service import FleetWorker

    store = MemoryStore()
    clock = {"t": at(23, 7, 0)}
    sizing = FleetSolver(
        store,
        _NoRuns(),
        SizingConfig(days=3),
        render=render_recommendation,
        cities=tiny_cities,
        clock=lambda: clock["t"],
    )
    status = WorkerStatus(embedded=True, poll_s=1.0, clock=lambda: clock["t"])
    worker = FleetWorker(sizing, [CITY], clock=lambda: clock["t"], status=status)
    with caplog.at_level(logging.WARNING):
        outcomes = [*worker.tick(), *worker.tick()]  # 07:00: the 08:00 solve is due; tried once
        clock["t"] = at(23, 8, 0)
        outcomes += worker.tick()  # 08:00: the 09:00 solve, the same reason
    assert [(o.status, o.waiting_for) for o in outcomes] == [("waiting", "insufficient_history")] * 2
    assert outcomes[0].reason is not None and outcomes[0].reason.startswith("collecting history: 0 of 3 days")
    assert caplog.text.count("not sized, no run started") == 1
    beat = status.beat(CITY)
    assert beat.waiting is not None and beat.waiting.kind == "insufficient_history"
    assert beat.waiting.since_s == at(23, 7, 0)
    assert store.recommendation_history(CITY, 10) == []
    store.enqueue_solve_request(CITY, SolveRequest("req-1", clock["t"], "admin"))
    (asked,) = worker.tick()
    assert asked.status == "waiting" and asked.request_id == "req-1"
    (entry,) = store.recommendation_history(CITY, 10)
    assert entry.status == "failed" and entry.request_id == "req-1" and entry.reason == asked.reason


def test_the_status_asks_for_a_beat_when_a_solves_runs_move_not_when_one_starts() -> None:
    """A solve of a few short runs can end within one heartbeat interval: the count of runs known, finished
    or failed asks the heartbeat to beat at once, so a dashboard sees the runs; a run starting does not."""
    from app.runs.runner import Progress
    from app.worker.heartbeat import WorkerStatus

    status = WorkerStatus(embedded=True, poll_s=1.0, clock=lambda: 0.0)
    status.progress(Progress(6, 0, 0, 0))  # no solve in progress: nothing to show
    assert not status.changed.is_set() and status.beat(CITY).solving is None
    asked: list[bool] = []
    with status.solving(CITY, 9, "request", "req-1"):
        status.changed.clear()
        for p in [Progress(6, 0, 0, 0), Progress(6, 0, 0, 0, running=1), Progress(6, 1, 0, 0, running=0)]:
            status.progress(p)
            asked.append(status.changed.is_set())
            status.changed.clear()
        status.progress(Progress(6, 2, 0, 1))
        solving = status.beat(CITY).solving
        assert solving is not None
        assert (solving.runs_total, solving.runs_done, solving.runs_failed) == (6, 2, 1)
        assert status.changed.is_set()
    assert asked == [True, False, True]
