"""The fleet-sizing worker end to end: real whole-day simulations of Chengdu with a tiny configuration
(sizes 2 and 4, 3 days, 4 ordinary taxis, 3 POI tasks, 10 requests an hour), published through the memory
store and a real Redis, and served by the API."""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.adapters import MemoryStore, RedisStore
from app.adapters.city_registry import CityRegistry
from app.bootstrap import create_app
from app.entrypoints.worker import main as worker_main
from app.ports import EpochCommit, SolveRequest, Store, local_day
from app.runs import (
    ProcessExecutor,
    ProgressFn,
    RunBatch,
    RunCache,
    RunJob,
    Runner,
    RunResult,
    RunSpec,
    demand_for,
    open_bundle,
    run_job,
)
from app.schemas.fleet import render_recommendation
from app.settings import Settings
from app.usecases.fleet_history import SizingConfig
from app.usecases.fleet_solve import FleetSolver, SolveOutcome
from app.worker.heartbeat import Heartbeat, WorkerStatus
from app.worker.service import FleetWorker
from services.sim.demand import DemandSet, Request

CITY = "chengdu"
TINY = SizingConfig(sizes=(2, 4), days=3, n0=4, n_tasks=3, rate_per_hour=10.0, lookback_days=9)
SHANGHAI = ZoneInfo("Asia/Shanghai")
BUNDLE = open_bundle(CityRegistry().bundle_dir(CITY))
TOKEN, ADMIN = "tok-read-worker-1", "tok-admin-worker1"


def local(day: int, hour: int, minute: int = 0) -> float:
    return dt.datetime(2026, 11, day, hour, minute, tzinfo=SHANGHAI).timestamp()


class Clock:
    """A settable clock shared by the worker and the solve."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


@pytest.fixture(params=["memory", "redis"])
def make_store(request: pytest.FixtureRequest) -> Iterator[Callable[[], Store]]:
    """Factory of store objects on one shared state: the same MemoryStore, or RedisStores (each with its own
    connections, like separate processes) under one fresh prefix."""
    if request.param == "memory":
        shared = MemoryStore()
        yield lambda: shared
        return
    url: str = request.getfixturevalue("redis_url")
    prefix: str = request.getfixturevalue("redis_prefix")
    made: list[RedisStore] = []

    def make() -> Store:
        made.append(RedisStore(url, prefix=prefix))
        return made[-1]

    yield make
    for s in made:
        s.close()


def worker(
    store: Store,
    cache: Path,
    clock: Clock,
    config: SizingConfig = TINY,
    runner: Runner | None = None,
    status: WorkerStatus | None = None,
) -> FleetWorker:
    progress = None if status is None else status.progress
    sizing = FleetSolver(
        store,
        runner or Runner(RunCache(cache)),
        config,
        render=render_recommendation,
        cities=CityRegistry(),
        clock=clock,
        progress=progress,
    )
    return FleetWorker(sizing, [CITY], lead_s=3600.0, poll_s=0.05, clock=clock, status=status)


def client_for(store: Store, clock: Callable[[], float] | None = None) -> TestClient:
    settings = Settings().with_values(tokens={TOKEN: ["read"], ADMIN: ["admin"]})
    return TestClient(create_app(settings, store=store, clock=clock))


def auth(token: str = TOKEN) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def current_body(store: Store) -> dict[str, Any]:
    """The current recommendation's document (there must be one)."""
    record = store.current_recommendation(CITY)
    assert record is not None and record.body_json is not None
    doc: dict[str, Any] = json.loads(record.body_json)
    return doc


def only(outcomes: Sequence[SolveOutcome]) -> SolveOutcome:
    assert len(outcomes) == 1, outcomes
    return outcomes[0]


def test_hourly_solves_publish_and_later_hours_reuse_the_runs(
    make_store: Callable[[], Store], tmp_path: Path
) -> None:
    store = make_store()
    clock = Clock(local(23, 6, 30))
    w = worker(store, tmp_path, clock)
    assert w.tick() == []  # 08:00 is 90 min away: not due
    clock.t = local(23, 7, 0)
    first = only(w.tick())
    assert (first.status, first.version) == ("published", 1)
    assert w.tick() == []  # tried once per hour
    body = current_body(store)
    assert body["interval"] == "2026-11-23T08:00" and body["trigger"] == "schedule"
    assert body["solve"]["runs"] == 6 and body["solve"]["cached_runs"] == 0
    assert body["data_window"]["source"] == "synthetic"
    assert body["data_window"]["days"] == ["synthetic-1", "synthetic-2", "synthetic-3"]

    # the same numbers a direct run of each job gives: total cost per hour = Step 3 cost / 4 h (ζ = 0), every
    # day with the one seeded task set
    assert body["simulation"]["tasks_source"] == "synthetic" and body["observed"]["hours"] == 0
    for i, row in enumerate(body["candidates"]):
        specs = [
            RunSpec(CITY, n1=row["size"], n0=4, day=d, n_tasks=3, rate_per_hour=10.0, tasks_day=0)
            for d in (1, 2, 3)
        ]
        runs = [run_job(RunJob(spec, BUNDLE.directory)) for spec in specs]
        assert row["samples"] == pytest.approx([r.kpis.monitoring_cost_cny / 4.0 for r in runs], rel=1e-12)
        assert row["mean_cost_cny_per_h"] == pytest.approx(np.mean(row["samples"]), rel=1e-12)
        assert row["design_kpi_mean"] == pytest.approx(row["mean_cost_cny_per_h"] / row["size"], rel=1e-12)
        hour0 = body["dro_rh_by_hour"][0]["candidates"][i]
        assert hour0["samples"] == pytest.approx(
            [r.kpis.hours[0].monitoring_cost_cny for r in runs], rel=1e-12
        )
        assert len({tuple((t.node, t.scheduled_at_s % 86400) for t in r.kpis.tasks) for r in runs}) == 1
    assert body["data_window"]["requests_per_day"] == [
        len(demand_for(RunSpec(CITY, day=d, rate_per_hour=10.0), BUNDLE).requests) for d in (1, 2, 3)
    ]

    clock.t = local(23, 8, 0)
    second = only(w.tick())
    assert (second.status, second.version) == ("published", 2)
    body2 = current_body(store)
    assert body2["interval"] == "2026-11-23T09:00" and body2["position"] == 1
    assert body2["solve"]["cached_runs"] == 6  # the whole-day runs of the 08:00 solve
    assert body2["candidates"] == body["candidates"]

    with client_for(store) as client:
        r = client.get(f"/v1/cities/{CITY}/fleet/recommendation", headers=auth())
        assert r.status_code == 200, r.text
        rec = r.json()
        assert rec["version"] == 2 and rec["interval"] == "2026-11-23T09:00"
        assert rec["computed_at"] == "2026-11-23T08:00:00+08:00"
        assert rec["chosen"]["dro_rh"] == rec["dro_rh_by_hour"][1]["size"] == rec["dro_rh"]["size"]
        history = client.get(f"/v1/cities/{CITY}/fleet/recommendations", headers=auth()).json()["entries"]
        assert [(e["status"], e["version"], e["interval"]) for e in history] == [
            ("published", 2, "2026-11-23T09:00"),
            ("published", 1, "2026-11-23T08:00"),
        ]


T = TypeVar("T")
R = TypeVar("R")


class CountingRunner(Runner):
    def __init__(self, cache: RunCache) -> None:
        super().__init__(cache)
        self.batches = 0
        self.calls = 0  # the sizing after the runs, sent where they went

    def run(self, jobs: Sequence[RunJob], progress: ProgressFn | None = None) -> RunBatch:
        self.batches += 1
        return super().run(jobs, progress)

    def call(self, fn: Callable[[T], R], item: T) -> R:
        self.calls += 1
        return super().call(fn, item)


def test_two_workers_racing_for_one_hour_solve_it_once(
    make_store: Callable[[], Store], tmp_path: Path
) -> None:
    clock = Clock(local(23, 7, 0))
    runners = [CountingRunner(RunCache(tmp_path / f"cache-{i}")) for i in range(2)]  # no shared cache
    workers = [worker(make_store(), tmp_path, clock, runner=r) for r in runners]
    barrier = threading.Barrier(2)
    seen: list[list[str]] = [[], []]

    def race(i: int) -> None:
        barrier.wait()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            statuses = [o.status for o in workers[i].tick()]
            seen[i] += statuses
            if statuses and statuses[-1] != "busy":
                return
            time.sleep(0.05)  # busy: the other holds the hour's lock; try again at the next poll

    threads = [threading.Thread(target=race, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    finals = sorted(s[-1] for s in seen)
    assert finals == ["published", "skipped"], seen
    assert sum(r.batches for r in runners) == 1  # exactly one solve simulated anything
    assert sum(r.calls for r in runners) == 1  # and sized its runs, through its runner's executor
    store = make_store()
    assert [(h.status, h.version) for h in store.recommendation_history(CITY, 10)] == [("published", 1)]


def fail_size_4(job: RunJob) -> RunResult:
    """A simulation that breaks for fleet size 4 (module level: the runner may send it to processes)."""
    if job.spec.n1 == 4:
        raise RuntimeError("size 4 broke")
    return run_job(job)


def slow_run_job(job: RunJob) -> RunResult:
    """A simulation that takes 0.2 s longer (so that a test can watch a solve's progress)."""
    time.sleep(0.2)
    return run_job(job)


def test_a_failing_simulation_keeps_the_last_good_recommendation(
    make_store: Callable[[], Store], tmp_path: Path
) -> None:
    store = make_store()
    clock = Clock(local(23, 7, 0))
    assert only(worker(store, tmp_path / "good", clock).tick()).status == "published"
    good = store.current_recommendation(CITY)

    clock.t = local(23, 7, 20)
    store.enqueue_solve_request(CITY, SolveRequest("req-broken", clock.t, "admin"))
    broken = worker(store, tmp_path / "b", clock, runner=Runner(RunCache(tmp_path / "b"), run_fn=fail_size_4))
    out = broken.requested(CITY)
    assert out is not None
    assert out.status == "failed" and out.request_id == "req-broken"
    assert out.reason is not None and "3 of 6 runs failed (partial solve)" in out.reason
    assert "RuntimeError: size 4 broke" in out.reason
    assert store.current_recommendation(CITY) == good
    history = store.recommendation_history(CITY, 10)
    assert [(h.status, h.version, h.request_id) for h in history] == [
        ("failed", None, "req-broken"),
        ("published", 1, None),
    ]
    assert broken.metrics.solves.labels(outcome="failed")._value.get() == 1

    with client_for(store) as client:
        rec = client.get(f"/v1/cities/{CITY}/fleet/recommendation", headers=auth()).json()
        assert rec["version"] == 1 and rec["interval"] == "2026-11-23T08:00"
        entries = client.get(f"/v1/cities/{CITY}/fleet/recommendations", headers=auth()).json()["entries"]
        assert entries[0]["status"] == "failed" and "size 4 broke" in entries[0]["reason"]

    # the runs that finished were cached: a retry with a working simulator only redoes size 4
    store.enqueue_solve_request(CITY, SolveRequest("req-retry", clock.t, "admin"))
    retry = worker(store, tmp_path / "b", clock).requested(CITY)
    assert retry is not None
    assert (retry.status, retry.version, retry.request_id) == ("published", 2, "req-retry")
    body = current_body(store)
    assert body["solve"]["cached_runs"] == 3 and body["trigger"] == "request"
    assert good is not None and good.body_json is not None
    assert body["candidates"] == json.loads(good.body_json)["candidates"]


def test_an_admin_request_is_picked_up_at_the_next_poll(tmp_path: Path) -> None:
    """No heartbeat: the request is refused (503 no_worker) and nothing queued. With the worker beating, the
    request is queued, the status shows the solve with its runs while it runs, then the recommendation."""
    store = MemoryStore()
    clock = Clock(local(23, 12, 30))  # after the horizon: nothing is due on schedule
    status = WorkerStatus(embedded=False, poll_s=0.05, clock=clock)
    slow = Runner(RunCache(tmp_path), run_fn=slow_run_job)  # each run takes 0.2 s more: progress to see
    w = worker(store, tmp_path, clock, runner=slow, status=status)
    assert w.tick() == []
    heartbeat = Heartbeat(w.sizing, status, [CITY], interval_s=0.05)
    solve_url, status_url = f"/v1/cities/{CITY}/fleet/solve", f"/v1/cities/{CITY}/fleet/status"
    with client_for(store, clock) as client:
        r = client.post(solve_url, headers=auth(ADMIN))
        assert r.status_code == 503 and r.json()["error"] == "no_worker", r.text
        assert store.pending_solve_request(CITY) is None
        heartbeat.start()
        try:
            r = client.post(solve_url, headers=auth(ADMIN))
            assert r.status_code == 202, r.text
            request_id = r.json()["request_id"]
            st = client.get(status_url, headers=auth()).json()
            assert st["worker"]["seen"] and st["pending_request"]["request_id"] == request_id
            assert st["next_scheduled"] == {
                "interval": "2026-11-24T08:00",
                "due_at": "2026-11-24T07:00:00+08:00",
            }
            assert client.get(f"/v1/cities/{CITY}/fleet/recommendation", headers=auth()).status_code == 404
            stop = threading.Event()
            loop = threading.Thread(target=w.run, args=(stop,))
            loop.start()
            seen: list[dict[str, Any]] = []
            try:
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline:
                    st = client.get(status_url, headers=auth()).json()
                    if st["solving"] is not None:
                        seen.append(st["solving"])
                    r = client.get(f"/v1/cities/{CITY}/fleet/recommendation", headers=auth())
                    if r.status_code == 200:
                        break
                    time.sleep(0.05)
            finally:
                stop.set()
                loop.join()
        finally:
            heartbeat.stop()
        rec = r.json()
        assert r.status_code == 200 and rec["request_id"] == request_id and rec["trigger"] == "request"
        assert rec["interval"] == "2026-11-24T08:00"  # the coming hour of the horizon
        assert seen and {s["request_id"] for s in seen} == {request_id}
        assert {s["runs_total"] for s in seen if s["runs_total"]} == {6}  # 2 sizes x 3 days
        done = [s["runs_done"] for s in seen]
        assert done == sorted(done) and len(set(done)) > 1, done  # progress moved while it was watched
        st = client.get(status_url, headers=auth()).json()
        assert st["solving"] is None and st["pending_request"] is None
        assert st["last_solve"]["status"] == "published" and st["last_solve"]["request_id"] == request_id
    assert w.tick() == []  # the request was consumed


def recorded_epochs(demand: DemandSet, ids: np.ndarray, epoch_s: int = 200, patience: int = 2) -> list[str]:
    """The set's riders as the service records them: every rider in the epochs from its request on, for
    ``patience`` epochs (a waiting rider recurs)."""
    start = int(min(r.time_s for r in demand.requests)) // epoch_s * epoch_s
    end = int(max(r.time_s for r in demand.requests)) + patience * epoch_s
    out = []
    for t in range(start + epoch_s, end + epoch_s, epoch_s):
        riders = [
            {"id": r.id, "origin": int(ids[r.origin]), "destination": int(ids[r.destination]),
             "requested_at": "", "requested_at_s": r.time_s}
            for r in demand.requests
            if r.time_s <= t < r.time_s + patience * epoch_s
        ]  # fmt: skip
        out.append(json.dumps({"epoch_id": f"{demand.date}-{t}", "time_s": float(t), "riders": riders}))
    return out


def record_demand(store: Store, demand: DemandSet) -> None:
    """Commit the set's riders as epochs, as the API records them."""
    for doc in recorded_epochs(demand, BUNDLE.city.network.node_ids):
        t = json.loads(doc)["time_s"]
        version = store.load_state(CITY, [], []).version
        day = local_day(t, BUNDLE.city.horizon.timezone)
        commit = EpochCommit(f"e{t}", "h", t, version, (), (), "{}", demand_json=doc, demand_day=day)
        assert store.commit_epoch(CITY, commit).status == "committed"


def test_recorded_demand_is_used_once_m_days_exist(tmp_path: Path) -> None:
    city = BUNDLE.city
    store = MemoryStore()
    dates = ["2026-11-21", "2026-11-22"]
    expected = []
    for d, date in enumerate(dates, start=7):
        synthetic = demand_for(RunSpec(CITY, day=d, rate_per_hour=10.0), BUNDLE)
        shift = city.horizon.start_s(date) - city.horizon.start_s(synthetic.date)
        moved = tuple(
            Request(f"{date}-{r.id}", r.time_s + shift, r.origin, r.destination) for r in synthetic.requests
        )
        expected.append(len(moved))
        record_demand(store, dataclasses.replace(synthetic, date=date, requests=moved))
    config = dataclasses.replace(TINY, days=2)
    out = worker(store, tmp_path, Clock(local(23, 7, 0)), config).tick()
    assert only(out).status == "published"
    window = current_body(store)["data_window"]
    assert window["source"] == "recorded" and window["days"] == ["2026-11-22", "2026-11-21"]
    assert window["requests_per_day"] == expected[::-1] and window["seed"] is None
    simulation = current_body(store)["simulation"]  # these records carry no fleet: the settings' sizes
    assert (simulation["sizes_source"], simulation["n0_source"], simulation["n0"]) == (
        "settings",
        "settings",
        4,
    )
    assert simulation["fleet_start"] == "seeded" and simulation["posted_instrumented"] is None


def test_the_rolling_recommendation_conditions_on_the_hours_recorded_today(tmp_path: Path) -> None:
    """Today's 08:00 and 09:00 requests are recorded; the 10:00 solve (for 11:00) keeps the two history days
    whose 08:00 and 09:00 volumes are closest to today's, for every hour from 11:00 on; 08:00 keeps all."""
    city = BUNDLE.city
    store = MemoryStore()
    today = "2026-11-23"
    synthetic = demand_for(RunSpec(CITY, day=7, rate_per_hour=10.0), BUNDLE)
    shift = city.horizon.start_s(today) - city.horizon.start_s(synthetic.date)
    two_hours = city.horizon.start_s(today) + 7200
    moved = tuple(
        Request(f"t-{r.id}", r.time_s + shift, r.origin, r.destination)
        for r in synthetic.requests
        if r.time_s + shift < two_hours - 600  # recorded epochs go on a little past the last request
    )
    record_demand(store, dataclasses.replace(synthetic, date=today, requests=moved))
    config = dataclasses.replace(TINY, rolling_days=2)
    assert only(worker(store, tmp_path, Clock(local(23, 10, 0)), config).tick()).status == "published"
    body = current_body(store)
    assert body["interval"] == "2026-11-23T11:00" and body["observed"]["hours"] == 2
    start = city.horizon.start_s(today)
    seen = [sum(1 for r in moved if start + 3600 * h <= r.time_s < start + 3600 * (h + 1)) for h in (0, 1)]
    assert body["observed"]["requests_per_hour"] == seen
    # the history days' hourly volumes, from direct runs; the two closest by RMS of log(1 + volume)
    volumes = []
    for d in (1, 2, 3):
        run = run_job(
            RunJob(
                RunSpec(CITY, n1=2, n0=4, day=d, n_tasks=3, rate_per_hour=10.0, tasks_day=0), BUNDLE.directory
            )
        )
        volumes.append([h.requests for h in run.kpis.hours])
    dist = [np.sqrt(np.mean((np.log1p(seen) - np.log1p(v[:2])) ** 2)) for v in volumes]
    kept = sorted(sorted(range(3), key=lambda j: (dist[j], j))[:2])
    by_hour = body["dro_rh_by_hour"]
    assert (
        by_hour[0]["days"] == ["synthetic-1", "synthetic-2", "synthetic-3"]
        and by_hour[0]["observed_hours"] == 0
    )
    assert by_hour[1]["observed_hours"] == 1 and by_hour[3]["observed_hours"] == 2
    assert by_hour[3]["days"] == [f"synthetic-{j + 1}" for j in kept] == by_hour[2]["days"]
    assert body["dro_rh"] == by_hour[3] and all(len(c["samples"]) == 2 for c in by_hour[3]["candidates"])


def test_two_processes_give_the_same_runs_as_one(tmp_path: Path) -> None:
    city = BUNDLE.city
    sizing = FleetSolver(
        MemoryStore(),
        Runner(RunCache(tmp_path / "unused")),
        TINY,
        render=render_recommendation,
        cities=CityRegistry(),
    )
    k = city.horizon.interval_of(local(23, 8))
    jobs = list(sizing.jobs(city, sizing.window(city, k, TINY), TINY).values())
    pooled = Runner(RunCache(tmp_path / "pool"), ProcessExecutor(2))
    try:
        two = pooled.run(jobs)
    finally:
        pooled.close()
    one = Runner(RunCache(tmp_path / "single")).run(jobs)
    assert two.failures == {} and two.cached == 0 and len(two.results) == 6

    def numbers(batch: RunBatch) -> dict[str, tuple[float, tuple[float, ...], int]]:
        return {
            k: (r.kpis.design_kpi, tuple(h.monitoring_cost_cny for h in r.kpis.hours), r.n_requests)
            for k, r in batch.results.items()
        }

    assert numbers(two) == numbers(one)


def test_worker_command_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("SD_STORE", "memory")
    monkeypatch.setenv("SD_VAR_DIR", str(tmp_path))
    argv = ["--once", "--city", CITY, "--sizes", "2,4", "--days", "3", "--tasks", "3", "--n0", "4",
            "--rate", "10", "--jobs", "1"]  # fmt: skip
    assert worker_main(argv) == 0
    assert "published version 1" in capsys.readouterr().out
    assert len(list((tmp_path / "fleet-runs").glob("*.json"))) == 6
    assert worker_main(["--once", "--city", "atlantis"]) == 2
    assert "unknown cities" in capsys.readouterr().err
