"""The runner: every job's result from the cache or from the executor, with progress as runs start and
finish."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeVar, cast

from app.runs.cache import ResultCache
from app.runs.executor import Executor, ExecutorUnavailable, Finished, InlineExecutor, Started
from app.runs.result import RunResult
from app.runs.spec import RunJob
from app.runs.workload import run_job

T = TypeVar("T")
R = TypeVar("R")

__all__ = ["RunFn", "Progress", "ProgressFn", "RunBatch", "Runner", "CallFailed"]


class CallFailed(RuntimeError):
    """A function ``Runner.call`` ran on the executor raised (its message: the executor's reason)."""


RunFn = Callable[[RunJob], RunResult]


@dataclass(frozen=True, slots=True)
class Progress:
    """Where a batch stands: ``done`` of ``total`` jobs finished (``cached`` of them read from the cache,
    ``failed`` of them raised), ``running`` on a worker now; ``retried`` counts the restarts of runs whose
    worker was lost (the engine ran them again elsewhere)."""

    total: int
    done: int
    cached: int
    failed: int
    running: int = 0
    retried: int = 0

    @property
    def queued(self) -> int:
        """Jobs neither finished nor running yet."""
        return self.total - self.done - self.running


ProgressFn = Callable[[Progress], None]


@dataclass(frozen=True, slots=True)
class RunBatch:
    """The outcome of a batch: results and failures by job key, how many came from the cache."""

    results: dict[str, RunResult]
    failures: dict[str, str] = field(default_factory=dict)
    cached: int = 0
    wall_s: float = 0.0


class Runner:
    """Runs jobs on an executor, reading and filling a cache; a job is never run twice for one key.

    ``run_fn`` (default ``app.runs.workload.run_job``) must be a module-level function when the
    executor sends work to other processes. A batch whose jobs are all cached never touches the executor.
    """

    def __init__(
        self, cache: ResultCache, executor: Executor | None = None, run_fn: RunFn | None = None
    ) -> None:
        self.cache = cache
        self.executor: Executor = executor or InlineExecutor()
        self.run_fn = run_fn

    @property
    def workers(self) -> int:
        """How many runs execute at once."""
        return self.executor.workers

    def run(self, jobs: Sequence[RunJob], progress: ProgressFn | None = None) -> RunBatch:
        """Every job's result (cached or computed) or the reason it failed; ``progress`` is called once
        before any run and whenever a run starts or finishes.

        Raises ``ExecutorUnavailable`` when the executor cannot run anything (nothing is cached then).
        """
        started = time.perf_counter()
        # bundle paths travel with the jobs to other processes and machines: make them absolute here
        unique = [
            j if j.bundle.is_absolute() else dataclasses.replace(j, bundle=j.bundle.absolute())
            for j in {j.key: j for j in jobs}.values()
        ]
        results: dict[str, RunResult] = {}
        failures: dict[str, str] = {}
        todo: list[RunJob] = []
        for job in unique:
            hit = self.cache.get(job.key)
            if hit is not None:
                results[job.key] = hit
            else:
                todo.append(job)
        cached = len(results)
        todo.sort(key=lambda j: j.cost, reverse=True)  # the longest first: the workers finish together

        running: set[int] = set()
        starts = [0] * len(todo)

        def report() -> None:
            if progress is not None:
                done = len(results) + len(failures)
                retried = sum(max(0, n - 1) for n in starts)
                progress(Progress(len(unique), done, cached, len(failures), len(running), retried))

        report()
        if todo:
            for bundle in dict.fromkeys(j.bundle for j in todo):
                self.executor.ship(bundle)
            fn = self.run_fn or run_job  # looked up per batch (a test may replace it)
            for event in self.executor.map_unordered(fn, todo, [j.key for j in todo]):
                job = todo[event.index]
                if job.key in results or job.key in failures:
                    continue  # a late start report of a finished run
                if isinstance(event, Started):
                    starts[event.index] += 1
                    running.add(event.index)
                else:
                    running.discard(event.index)
                    if event.value is None:
                        failures[job.key] = event.error or "failed without a reason"
                    else:
                        self.cache.put(event.value)
                        results[job.key] = event.value
                report()
        return RunBatch(results, failures, cached, time.perf_counter() - started)

    def call(self, fn: Callable[[T], R], item: T) -> R:
        """``fn(item)`` on the executor, where the runs go (so the service's epochs pause it with them);
        ``fn`` must be a module-level function when the executor sends work to other processes.

        Raises ``CallFailed`` with the executor's reason when it raised, ``ExecutorUnavailable`` when
        nothing can run."""
        for event in self.executor.map_unordered(fn, [item]):
            if isinstance(event, Finished):
                if event.error is not None:
                    raise CallFailed(event.error)
                return cast(R, event.value)
        raise ExecutorUnavailable("the executor ended without an outcome")

    def close(self) -> None:
        """Release the executor's workers."""
        self.executor.close()
