"""The fleet worker's runs on a real Dask cluster: a scheduler and two workers, each a separate process on
free loopback ports (``app.runs.localcluster``). A small re-solve (Chengdu, sizes 2 and 4, 3 days,
4 ordinary taxis, 3 POI tasks, 10 requests an hour: 6 short runs) must equal the local executor's bit for
bit -- also when a worker process is killed in the middle of the runs; a lost cluster keeps the last good
recommendation."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import httpx
import pytest

from app.adapters import MemoryStore
from app.adapters.city_registry import CityRegistry
from app.entrypoints.worker import main as worker_main
from app.runs import Event, Executor, Progress, RunCache, RunJob, Runner, RunResult, Started
from app.runs.dask_executor import DaskExecutor
from app.runs.localcluster import LocalCluster, free_port
from app.runs.workload import open_bundle
from app.schemas.fleet import render_recommendation
from app.usecases.fleet_solve import FleetSolver
from app.worker.service import WorkerMetrics
from services.model import IntervalKey
from tests.e2e.cluster_tasks import where_opened
from tests.e2e.test_worker import CITY, TINY, Clock, local

T = TypeVar("T")
R = TypeVar("R")

CLOCK_FIELDS = ("elapsed_s", "cpu_s", "solve_ms_median")  # clock readings: the only fields that may differ


def sizing(
    runner: Runner, store: MemoryStore, progress: Callable[[Progress], None] | None = None
) -> FleetSolver:
    return FleetSolver(
        store,
        runner,
        TINY,
        render=render_recommendation,
        cities=CityRegistry(),
        clock=Clock(local(23, 7, 0)),
        progress=progress,
    )


def target() -> IntervalKey:
    return open_bundle(CityRegistry().bundle_dir(CITY)).city.horizon.interval_of(local(23, 8))


def tiny_jobs() -> list[RunJob]:
    """The small re-solve's 6 jobs."""
    s = sizing(Runner(RunCache(Path("unused"))), MemoryStore())
    city = s.load_city(CITY)
    return list(s.jobs(city, s.window(city, target(), TINY), TINY).values())


def body_of(store: MemoryStore) -> dict[str, Any]:
    """The current recommendation without its solve statistics (wall time, jobs, cached runs)."""
    record = store.current_recommendation(CITY)
    assert record is not None and record.body_json is not None
    doc: dict[str, Any] = json.loads(record.body_json)
    del doc["solve"]
    return doc


def without_clocks(run: RunResult) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(run.to_json())
    del doc["elapsed_s"], doc["cpu_s"]
    del doc["kpis"]["solve_ms_median"]
    return doc


def cached_runs(directory: Path) -> dict[str, dict[str, Any]]:
    cache = RunCache(directory)
    out = {}
    for path in sorted(directory.glob("*.json")):
        run = cache.get(path.stem)
        assert run is not None
        out[path.stem] = without_clocks(run)
    return out


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    """The small re-solve on the local executor (this process): its recommendation and its run cache."""
    cache = tmp_path_factory.mktemp("local-runs")
    store = MemoryStore()
    assert sizing(Runner(RunCache(cache)), store).solve(CITY, target()).status == "published"
    return body_of(store), cache


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalCluster]:
    with LocalCluster(2, tmp_path_factory.mktemp("cluster")) as c:
        yield c


class OnFirstStart:
    """An executor that does ``act(started)`` the moment the first run reports its start, then goes on."""

    def __init__(self, inner: Executor, act: Callable[[Started], None]) -> None:
        self.inner = inner
        self.act = act
        self.first: Started | None = None

    @property
    def workers(self) -> int:
        return self.inner.workers

    def ship(self, bundle: Path) -> None:
        self.inner.ship(bundle)

    def map_unordered(
        self, fn: Callable[[T], R], items: Sequence[T], keys: Sequence[str] | None = None
    ) -> Iterator[Event[R]]:
        for event in self.inner.map_unordered(fn, items, keys):
            if isinstance(event, Started) and self.first is None:
                self.first = event
                self.act(event)
            yield event

    def close(self) -> None:
        self.inner.close()


def test_a_small_resolve_on_the_cluster_equals_the_local_one_bit_for_bit(
    cluster: LocalCluster, reference: tuple[dict[str, Any], Path], tmp_path: Path
) -> None:
    store, metrics = MemoryStore(), WorkerMetrics()
    seen: list[Progress] = []

    def progress(p: Progress) -> None:
        seen.append(p)
        metrics.progress(p)

    runner = Runner(RunCache(tmp_path), DaskExecutor(cluster.address))
    try:
        out = sizing(runner, store, progress).solve(CITY, target())
    finally:
        runner.close()
    assert out.status == "published", out.reason
    body, local_cache = reference
    assert body_of(store) == body
    assert cached_runs(tmp_path) == cached_runs(local_cache) and len(cached_runs(tmp_path)) == 6
    assert max(p.running for p in seen) <= 2  # two single-threaded workers
    # each run started at most once (a start reported after its run finished is dropped, so on a loaded
    # machine a tiny run may show no start at all), and at least one start was seen
    assert 1 <= sum(1 for a, b in zip(seen, seen[1:], strict=False) if b.running > a.running) <= 6
    state = {
        s: metrics.runs.labels(state=s)._value.get()
        for s in ("queued", "running", "done", "failed", "retried")
    }
    assert state == {"queued": 0, "running": 0, "done": 6, "failed": 0, "retried": 0}
    # the engine's own dashboard and its Prometheus metrics
    assert httpx.get(f"{cluster.dashboard}/status", timeout=10).status_code == 200
    assert "dask_scheduler_workers" in httpx.get(f"{cluster.dashboard}/metrics", timeout=10).text


def test_runs_read_the_bundle_shipped_to_their_worker(cluster: LocalCluster) -> None:
    bundle = CityRegistry().bundle_dir(CITY).resolve()
    executor = DaskExecutor(cluster.address)
    try:
        executor.ship(bundle)
        events = list(executor.map_unordered(where_opened, tiny_jobs()[:4]))
    finally:
        executor.close()
    opened = {e.value for e in events if not isinstance(e, Started)}
    assert [e.error for e in events if not isinstance(e, Started) and e.error] == []
    assert opened and all(p is not None and "/sd-bundles/chengdu-" in p for p in opened)
    assert all(p is not None and str(cluster.directory) in p for p in opened)  # the workers' own directories


def test_two_fleet_workers_on_one_cluster_simulate_each_run_once(
    cluster: LocalCluster, tmp_path: Path
) -> None:
    """The second worker submits the same runs while the first one's are running: one task per run key
    (the same result object: equal clock readings), not two simulations."""
    jobs = tiny_jobs()
    runners = [Runner(RunCache(tmp_path / f"w{i}"), DaskExecutor(cluster.address)) for i in range(2)]
    batches: list[Any] = [None, None]
    second = threading.Thread(target=lambda: batches.__setitem__(1, runners[1].run(jobs)))

    def start_second(p: Progress) -> None:
        if p.running and not second.is_alive() and batches[1] is None:
            second.start()

    try:
        batches[0] = runners[0].run(jobs, start_second)
        second.join(timeout=120)
    finally:
        for r in runners:
            r.close()
    assert batches[1] is not None and batches[0].failures == batches[1].failures == {}
    assert len(batches[0].results) == len(batches[1].results) == 6
    for key, run in batches[0].results.items():
        assert batches[1].results[key].elapsed_s == run.elapsed_s, key
        assert batches[1].results[key].cpu_s == run.cpu_s, key


def test_a_worker_killed_mid_run_is_retried_and_the_recommendation_is_the_same(
    cluster: LocalCluster, reference: tuple[dict[str, Any], Path], tmp_path: Path
) -> None:
    store = MemoryStore()
    seen: list[Progress] = []
    killer = OnFirstStart(DaskExecutor(cluster.address), lambda e: cluster.kill_worker(e.pid))
    runner = Runner(RunCache(tmp_path), killer)
    try:
        out = sizing(runner, store, seen.append).solve(CITY, target())
    finally:
        runner.close()
    assert killer.first is not None and killer.first.pid not in cluster.worker_pids()  # it is dead
    assert out.status == "published", out.reason
    assert seen[-1].retried >= 1 and seen[-1].failed == 0 and seen[-1].done == 6
    body, local_cache = reference
    assert body_of(store) == body
    assert cached_runs(tmp_path) == cached_runs(local_cache)
    cluster.add_worker()  # a replacement for the tests after this one


def test_a_lost_cluster_keeps_the_last_good_recommendation(
    reference: tuple[dict[str, Any], Path], tmp_path: Path
) -> None:
    body, local_cache = reference
    store = MemoryStore()
    assert sizing(Runner(RunCache(local_cache)), store).solve(CITY, target()).status == "published"
    good = store.current_recommendation(CITY)
    with LocalCluster(1, tmp_path / "cluster") as lost:
        address = lost.address
        executor = OnFirstStart(DaskExecutor(address, timeout_s=2.0), lambda e: lost.kill_scheduler())
        runner = Runner(RunCache(tmp_path / "runs"), executor)
        try:
            failed = sizing(runner, store).solve(CITY, target(), force=True)
            assert failed.status == "failed" and failed.reason is not None
            assert (
                "runs failed" in failed.reason
                and f"the Dask scheduler at {address} was lost" in failed.reason
            )
            assert store.current_recommendation(CITY) == good
            again = sizing(runner, store).solve(CITY, target(), force=True)
            assert again.status == "failed" and again.reason is not None
            assert f"cannot reach the Dask scheduler at {address}" in again.reason
            assert store.current_recommendation(CITY) == good
            # a solve whose runs are all cached still publishes without the cluster
            cached = Runner(RunCache(local_cache), executor)
            assert sizing(cached, store).solve(CITY, target(), force=True).status == "published"
        finally:
            runner.close()
    history = [(h.status, h.version) for h in store.recommendation_history(CITY, 10)]
    assert history == [("published", 2), ("failed", None), ("failed", None), ("published", 1)]
    assert body_of(store) == body


def test_worker_command_on_the_cluster(
    cluster: LocalCluster, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("SD_STORE", "memory")
    monkeypatch.setenv("SD_VAR_DIR", str(tmp_path))
    monkeypatch.setenv("SD_DASK_TIMEOUT_S", "2")
    argv = ["--once", "--city", CITY, "--sizes", "2,4", "--days", "3", "--tasks", "3", "--n0", "4",
            "--rate", "10", "--executor", "dask"]  # fmt: skip
    assert worker_main([*argv, "--scheduler", cluster.address]) == 0
    assert "published version 1" in capsys.readouterr().out
    assert len(list((tmp_path / "fleet-runs").glob("*.json"))) == 6
    nobody = f"tcp://127.0.0.1:{free_port()}"
    monkeypatch.setenv("SD_VAR_DIR", str(tmp_path / "empty"))
    assert worker_main([*argv, "--scheduler", nobody]) == 1
    assert f"cannot reach the Dask scheduler at {nobody}" in capsys.readouterr().out
    assert worker_main(argv) == 2  # dask without a scheduler address
    assert "SD_DASK_SCHEDULER" in capsys.readouterr().err
