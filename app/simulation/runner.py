"""The runner: every job's result from the cache or from the executor, with progress as runs finish."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from app.simulation.executor import Executor, InlineExecutor
from app.simulation.result import RunResult
from app.simulation.spec import RunJob
from app.simulation.workload import run_job

__all__ = ["RunFn", "Progress", "ProgressFn", "RunBatch", "RunCache", "Runner"]

log = logging.getLogger(__name__)

RunFn = Callable[[RunJob], RunResult]


@dataclass(frozen=True, slots=True)
class Progress:
    """Where a batch stands: ``done`` of ``total`` jobs finished (``cached`` of them read from the cache,
    ``failed`` of them raised)."""

    total: int
    done: int
    cached: int
    failed: int


ProgressFn = Callable[[Progress], None]


@dataclass(frozen=True, slots=True)
class RunBatch:
    """The outcome of a batch: results and failures by job key, how many came from the cache."""

    results: dict[str, RunResult]
    failures: dict[str, str] = field(default_factory=dict)
    cached: int = 0
    wall_s: float = 0.0


class RunCache:
    """Finished runs as ``<dir>/<key>.json`` (written to a temporary file, then renamed)."""

    def __init__(self, directory: Path) -> None:
        """Cache under ``directory`` (created on the first write)."""
        self.directory = directory

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.json"

    def get(self, key: str) -> RunResult | None:
        """The cached run, or ``None`` (an unreadable file counts as missing and is logged)."""
        path = self._path(key)
        try:
            return RunResult.from_json(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("ignoring unreadable cached run %s: %r", path, exc)
            return None

    def put(self, result: RunResult) -> None:
        """Store a run atomically."""
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self._path(result.key)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(result.to_json(), encoding="utf-8")
        tmp.replace(path)


class Runner:
    """Runs jobs on an executor, reading and filling a cache; a job is never run twice for one key.

    ``run_fn`` (default ``app.simulation.workload.run_job``) must be a module-level function when the
    executor sends work to other processes.
    """

    def __init__(
        self, cache: RunCache, executor: Executor | None = None, run_fn: RunFn | None = None
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
        before any run and after each finished one."""
        started = time.perf_counter()
        unique = list({j.key: j for j in jobs}.values())
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

        def report() -> None:
            if progress is not None:
                progress(Progress(len(unique), len(results) + len(failures), cached, len(failures)))

        report()
        fn = self.run_fn or run_job  # looked up per batch (a test may replace it)
        for out in self.executor.map_unordered(fn, todo):
            job = todo[out.index]
            if out.value is None:
                failures[job.key] = out.error or "failed without a reason"
            else:
                self.cache.put(out.value)
                results[job.key] = out.value
            report()
        return RunBatch(results, failures, cached, time.perf_counter() - started)

    def close(self) -> None:
        """Release the executor's workers."""
        self.executor.close()
