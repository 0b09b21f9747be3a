"""The executor seam: start and outcome events of the local executors, the runner's bookkeeping of them
(running, queued, retried, cached), shipping city bundles, and choosing an executor by name."""

from __future__ import annotations

import os
import shutil
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar, cast

import pytest

from app.runs import (
    Event,
    ExecutorUnavailable,
    Finished,
    InlineExecutor,
    ProcessExecutor,
    Progress,
    RunCache,
    RunJob,
    Runner,
    RunSpec,
    Started,
    make_executor,
    open_bundle,
)
from app.runs.bundles import BundleFiles, install_shipped, shipped_copy
from app.runs.executor import Foreground
from app.runs.localcluster import free_port
from app.runs.runner import CallFailed
from tests.api.fakes import CITY, build_bundle
from tests.unit.pool_tasks import (
    count_until_stopped,
    executor_then_die,
    exit_on_2,
    pid_and_square,
    square_unless_3,
)
from tests.unit.test_worker_parts import result

T = TypeVar("T")
R = TypeVar("R")


def test_inline_reports_each_start_before_its_outcome_and_goes_on_after_a_failure() -> None:
    events = list(InlineExecutor().map_unordered(square_unless_3, [2, 3, 4]))
    pid = os.getpid()
    assert events == [
        Started(0, f"pid {pid}", pid),
        Finished(0, 4),
        Started(1, f"pid {pid}", pid),
        Finished(1, error="ValueError: three"),
        Started(2, f"pid {pid}", pid),
        Finished(2, 16),
    ]


@pytest.mark.slow  # starting pool processes that import the simulation takes seconds
def test_local_processes_report_starts_from_their_own_pids_and_every_outcome() -> None:
    executor = ProcessExecutor(2)
    try:
        for _ in range(2):  # the pool is kept between batches; starts of one batch never leak into the next
            events = list(executor.map_unordered(square_unless_3, list(range(8))))
            starts = [e for e in events if isinstance(e, Started)]
            outcomes = {e.index: (e.value, e.error) for e in events if isinstance(e, Finished)}
            assert sorted(s.index for s in starts) == list(range(8))
            pids = {s.pid for s in starts}
            assert len(pids) <= 2 and os.getpid() not in pids
            assert all(s.worker == f"pid {s.pid}" for s in starts)
            assert outcomes == {
                i: ((None, "ValueError: three") if i == 3 else (i * i, None)) for i in range(8)
            }
    finally:
        executor.close()


@pytest.mark.slow
def test_a_call_runs_where_the_runs_go(tmp_path: Path) -> None:
    """``Runner.call`` (how a fleet solve's sizing follows its runs, so that an epoch pauses it with them):
    one function on the executor -- in a process of the pool, not this one, on local processes -- its value
    back; a raise is ``CallFailed`` with the executor's reason; inline, in this process."""
    executor = ProcessExecutor(1)
    try:
        runner = Runner(RunCache(tmp_path), executor)
        pid, value = runner.call(pid_and_square, 4)
        assert value == 16 and pid != os.getpid()
        with pytest.raises(CallFailed, match="ValueError: three"):
            runner.call(pid_and_square, 3)
    finally:
        executor.close()
    assert Runner(RunCache(tmp_path)).call(pid_and_square, 5) == (os.getpid(), 25)


@pytest.mark.slow
def test_a_dead_process_fails_the_items_it_held_and_the_next_batch_gets_a_new_pool() -> None:
    executor = ProcessExecutor(2)
    try:
        events = list(executor.map_unordered(exit_on_2, [0, 1, 2]))
        errors = {e.index: e.error for e in events if isinstance(e, Finished) and e.error}
        assert 2 in errors and "BrokenProcessPool" in str(errors[2])
        again = [e for e in executor.map_unordered(exit_on_2, [5, 6]) if isinstance(e, Finished)]
        assert sorted((e.index, e.value) for e in again) == [(0, 5), (1, 6)]
    finally:
        executor.close()


class Scripted:
    """An executor that plays a fixed sequence of events (and records what it was asked)."""

    workers = 2

    def __init__(self, script: Callable[[Sequence[Any]], list[Event[Any]]]) -> None:
        self.script = script
        self.shipped: list[Path] = []
        self.batches: list[tuple[list[Any], list[str] | None]] = []

    def ship(self, bundle: Path) -> None:
        self.shipped.append(bundle)

    def map_unordered(
        self, fn: Callable[[T], R], items: Sequence[T], keys: Sequence[str] | None = None
    ) -> Iterator[Event[R]]:
        self.batches.append((list(items), None if keys is None else list(keys)))
        yield from self.script(items)

    def close(self) -> None:
        pass


def jobs_of(*sizes: int, bundle: Path = Path("/bundles/chengdu")) -> list[RunJob]:
    return [RunJob(RunSpec(n1=x, day=1), bundle) for x in sizes]


def test_the_runner_counts_running_queued_and_retried_runs_from_the_events(tmp_path: Path) -> None:
    """Job 0 starts on w1, job 1 on w2; w1 dies and the engine restarts job 0 on w2 (a retry); a late start
    report of a finished job changes nothing."""
    jobs = jobs_of(40, 20, 10)  # the costliest first: items 0, 1, 2 are these jobs in this order

    def script(items: Sequence[RunJob]) -> list[Event[Any]]:
        return [
            Started(0, "w1", 11),
            Started(1, "w2", 12),
            Finished(1, result(items[1].key, 20)),
            Started(0, "w2", 12),
            Started(2, "w3", 13),
            Finished(0, result(items[0].key, 40)),
            Started(1, "w9", 19),
            Finished(2, error="KilledWorker: lost thrice"),
        ]

    seen: list[Progress] = []
    executor = Scripted(script)
    batch = Runner(RunCache(tmp_path), executor).run(jobs, seen.append)
    states = [(p.queued, p.running, p.done, p.failed, p.retried) for p in seen]
    assert states == [
        (3, 0, 0, 0, 0),
        (2, 1, 0, 0, 0),
        (1, 2, 0, 0, 0),
        (1, 1, 1, 0, 0),
        (1, 1, 1, 0, 1),  # job 0 again: one retry, still one running
        (0, 2, 1, 0, 1),
        (0, 1, 2, 0, 1),
        (0, 0, 3, 1, 1),
    ]
    assert set(batch.results) == {jobs[0].key, jobs[1].key}
    assert batch.failures == {jobs[2].key: "KilledWorker: lost thrice"}
    assert executor.batches[0][1] == [j.key for j in jobs]  # the engine gets the job keys as task names


def test_a_batch_whose_runs_are_all_cached_never_touches_the_executor(tmp_path: Path) -> None:
    class Unreachable(Scripted):
        def ship(self, bundle: Path) -> None:
            raise ExecutorUnavailable("cannot reach the Dask scheduler at tcp://nowhere:1")

    cache = RunCache(tmp_path)
    jobs = jobs_of(10, 20)
    for j in jobs:
        cache.put(result(j.key, j.spec.n1))
    runner = Runner(cache, Unreachable(lambda items: []))
    batch = runner.run(jobs)
    assert batch.cached == 2 and set(batch.results) == {j.key for j in jobs} and batch.failures == {}
    with pytest.raises(ExecutorUnavailable, match="cannot reach the Dask scheduler"):
        runner.run(jobs_of(10, 30))


def test_the_runner_ships_each_bundle_once_and_sends_absolute_paths(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    relative = jobs_of(10, 20, bundle=Path("cities/a")) + jobs_of(30, bundle=Path("/srv/cities/b"))

    def ok(items: Sequence[RunJob]) -> list[Event[Any]]:
        return [Finished(i, result(j.key, j.spec.n1)) for i, j in enumerate(items)]

    executor = Scripted(ok)
    batch = Runner(RunCache(tmp_path / "runs"), executor).run(relative)
    assert len(batch.results) == 3
    assert sorted(executor.shipped) == sorted([tmp_path / "cities" / "a", Path("/srv/cities/b")])
    assert {j.bundle for j in executor.batches[0][0]} == {tmp_path / "cities" / "a", Path("/srv/cities/b")}


def test_a_shipped_bundle_is_read_where_a_job_names_the_original(tmp_path: Path) -> None:
    original = build_bundle(tmp_path / "submitter") / CITY
    files = BundleFiles.read(original)
    assert {name for name, _ in files.files} == {p.name for p in original.iterdir()}
    assert files.size_bytes == sum(p.stat().st_size for p in original.iterdir())
    copy = install_shipped(files, tmp_path / "worker")
    assert install_shipped(files, tmp_path / "worker") == copy  # installed once per digest
    shutil.rmtree(original)  # the worker's machine does not have the submitter's path
    assert shipped_copy(original) == copy
    bundle = open_bundle(original)
    assert bundle.directory == copy and bundle.city.name == CITY
    assert shipped_copy(tmp_path / "elsewhere") == tmp_path / "elsewhere"

    changed = build_bundle(tmp_path / "submitter2") / CITY
    (changed / "city.json").write_text((changed / "city.json").read_text() + "\n")
    assert BundleFiles.read(changed).digest != files.digest
    with pytest.raises(ValueError, match="absolute"):
        BundleFiles.read(Path("relative/tiny"))


def test_executors_by_name() -> None:
    assert isinstance(make_executor(1), InlineExecutor)
    pool = make_executor(3)
    assert isinstance(pool, ProcessExecutor) and pool.workers == 3
    with pytest.raises(ValueError, match="SD_DASK_SCHEDULER"):
        make_executor(2, "dask")
    with pytest.raises(ValueError, match="unknown executor"):
        make_executor(2, "ray")  # type: ignore[arg-type]
    nobody = f"tcp://127.0.0.1:{free_port()}"
    dask = make_executor(2, "dask", scheduler=nobody, timeout_s=1.0)  # connects on first use only
    assert dask.workers == 0
    with pytest.raises(ExecutorUnavailable, match=f"cannot reach the Dask scheduler at {nobody}"):
        list(dask.map_unordered(square_unless_3, [1]))
    dask.close()


def _count(directory: Path) -> int:
    try:
        return int((directory / "count").read_text() or 0)
    except FileNotFoundError:
        return 0


def _until(check: Callable[[], bool], timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.02)


@pytest.mark.slow  # starting a pool process takes seconds
def test_paused_processes_make_no_progress_until_resumed(tmp_path: Path) -> None:
    """What the embedded worker's runs do while the API solves an epoch (``Foreground``): stopped where
    they are, then going on; closing a paused executor still ends its processes."""
    executor = ProcessExecutor(1)
    events: list[Any] = []
    runs = threading.Thread(
        target=lambda: events.extend(executor.map_unordered(count_until_stopped, [str(tmp_path)]))
    )
    runs.start()
    try:
        _until(lambda: _count(tmp_path) > 5)
        executor.pause()
        time.sleep(0.2)  # a write under way when the signal came is over
        held = _count(tmp_path)
        time.sleep(0.5)
        assert _count(tmp_path) == held  # no progress while paused
        executor.resume()
        _until(lambda: _count(tmp_path) > held + 5)
        (tmp_path / "stop").touch()
        runs.join(timeout=60)
        assert [e.value for e in events if isinstance(e, Finished)] == [_count(tmp_path)]
        executor.pause()
    finally:
        (tmp_path / "stop").touch()
        executor.close()  # resumes first: a stopped process would never take its shutdown
    assert not runs.is_alive()


def test_abandoned_runs_fail_their_batch_and_close_waits_for_none(tmp_path: Path) -> None:
    """A service ending mid-solve (the embedded worker's stop): a run that would go on until told, paused
    by an epoch in flight as well, is ended at once; its batch reports it failed and closing the executor
    waits for no run."""
    executor = ProcessExecutor(1)
    events: list[Any] = []
    runs = threading.Thread(
        target=lambda: events.extend(executor.map_unordered(count_until_stopped, [str(tmp_path)]))
    )
    runs.start()
    try:
        _until(lambda: _count(tmp_path) > 5 and any(isinstance(e, Started) for e in events))
        pid = next(e.pid for e in events if isinstance(e, Started))
        executor.pause()
        executor.abandon()
        runs.join(timeout=60)
        assert not runs.is_alive()  # the batch ended without the run's stop file
        executor.close()
    finally:
        (tmp_path / "stop").touch()
        executor.close()
    finished = [e for e in events if isinstance(e, Finished)]
    assert len(finished) == 1 and finished[0].error is not None and "BrokenProcessPool" in finished[0].error
    assert not _alive(pid)
    counted = _count(tmp_path)
    time.sleep(0.3)
    assert _count(tmp_path) == counted  # nothing counts on


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a process that has not ended (a zombie has ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


@pytest.mark.slow  # two processes and a pool start
def test_a_run_does_not_outlive_the_process_that_started_it(tmp_path: Path) -> None:
    """A service killed mid-solve (no shutdown) leaves no simulation running: the run's process is
    killed when its parent ends."""
    import multiprocessing

    parent = multiprocessing.get_context("spawn").Process(target=executor_then_die, args=(str(tmp_path),))
    parent.start()
    parent.join(timeout=120)
    assert parent.exitcode == 0
    pid = int((tmp_path / "pid").read_text())
    forkserver = int((tmp_path / "forkserver").read_text())
    try:
        _until(lambda: not _alive(pid))
    finally:  # the pool's forkserver, orphaned with the test's stand-in service, is this test's to end
        os.kill(forkserver, signal.SIGTERM)
    counted = _count(tmp_path)
    time.sleep(0.3)
    assert _count(tmp_path) == counted  # nothing counts on


class _Recorder:
    def __init__(self) -> None:
        self.calls: list[str] = []

    def pause(self) -> None:
        self.calls.append("pause")

    def resume(self) -> None:
        self.calls.append("resume")


def test_the_first_epoch_in_flight_pauses_and_the_last_resumes() -> None:
    gate = Foreground()
    first, second = _Recorder(), _Recorder()
    gate.add(first)  # type: ignore[arg-type]
    with gate.epoch():
        assert first.calls == ["pause"]
        with gate.epoch():  # a second epoch solved at the same time
            gate.add(second)  # type: ignore[arg-type]  # added while epochs are in flight: paused at once
            assert first.calls == ["pause"] and second.calls == ["pause"]
        assert first.calls == ["pause"]  # one epoch still in flight
    assert first.calls == second.calls == ["pause", "resume"]
    with pytest.raises(RuntimeError), gate.epoch():
        raise RuntimeError("an epoch that fails still resumes the runs")
    assert first.calls == ["pause", "resume", "pause", "resume"]


class _Parts:
    """An embedded worker's parts whose loop is in a solve: a run that goes on until told."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.executor = ProcessExecutor(1)
        self.runner = self
        self.heartbeat = self
        self.worker = self
        self.events: list[Any] = []

    def start(self) -> None:
        """The heartbeat's start."""

    def stop(self) -> None:
        """The heartbeat's stop."""

    def run(self, stop: threading.Event) -> None:
        self.events.extend(self.executor.map_unordered(count_until_stopped, [str(self.directory)]))

    def close(self) -> None:
        self.executor.close()


def test_stopping_the_embedded_worker_mid_solve_abandons_its_runs(tmp_path: Path) -> None:
    """The service's shutdown (``EmbeddedWorker.stop``) with a solve's run under way: the run is ended, the
    loop sees it fail and the worker stops, instead of waiting for the run (minutes on a metropolis)."""
    from app.worker.embedded import EmbeddedWorker

    parts = _Parts(tmp_path)
    worker = EmbeddedWorker(cast(Any, parts))
    worker.start()
    try:
        _until(lambda: _count(tmp_path) > 5)
        worker.stop(grace_s=0.5, timeout_s=60)
        assert worker._thread is not None and not worker._thread.is_alive()
    finally:
        (tmp_path / "stop").touch()
        parts.executor.close()
    finished = [e for e in parts.events if isinstance(e, Finished)]
    assert len(finished) == 1 and "BrokenProcessPool" in (finished[0].error or "")
