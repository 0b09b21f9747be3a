"""Whole-day simulation runs for fleet sizing: one per (fleet size, demand day), fanned out over processes
and cached on disk so later hours (and later solves over the same days) reuse them.

A run is described by a ``RunSpec`` (city, sizes, seed, day, tasks; see ``app.experiment.workload``) and,
for recorded demand, the ``DemandSet`` itself; synthetic days draw their demand with ``demand_for(spec)``.
The cache key names the spec, a digest of recorded demand and the simulator's and generator's versions, so
a changed input never reads a stale run. (A rebuilt city bundle is not part of the key: clear the cache
directory when a bundle changes.)
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

from app.experiment.workload import RunSpec, run_spec
from services.sim.demand import DEMAND_VERSION, DemandSet
from services.sim.engine import SIM_VERSION
from services.sim.kpi import run_kpis

__all__ = [
    "CACHE_FORMAT",
    "DayJob",
    "DayResult",
    "RunBatch",
    "DayRunner",
    "RunFn",
    "run_day",
    "RunCache",
    "PoolRunner",
]

log = logging.getLogger(__name__)

CACHE_FORMAT = "1"


@dataclass(frozen=True, slots=True)
class DayJob:
    """One whole-day run: the spec, and the recorded demand when the day is not synthetic."""

    spec: RunSpec
    demand: DemandSet | None = None

    @property
    def key(self) -> str:
        """Cache key (file-name safe): spec, recorded-demand digest, simulator and generator versions."""
        source = "syn" if self.demand is None else f"rec{demand_digest(self.demand)}"
        return f"{self.spec.key}-{source}-sim{SIM_VERSION}-dem{DEMAND_VERSION}-c{CACHE_FORMAT}"


def demand_digest(demand: DemandSet) -> str:
    """16 hex digits of sha256 over the set's date and requests."""
    h = hashlib.sha256(demand.date.encode())
    for r in demand.requests:
        h.update(f"\n{r.id}\t{int(r.time_s)}\t{r.origin}\t{r.destination}".encode())
    return h.hexdigest()[:16]


@dataclass(frozen=True, slots=True)
class DayResult:
    """The KPIs fleet sizing needs from one run (per hour: design KPI and monitoring cost)."""

    key: str
    size: int
    date: str
    n_requests: int
    design_kpi: float
    completion_rate: float
    hour_design_kpi: tuple[float, ...]
    hour_cost_cny: tuple[float, ...]
    elapsed_s: float

    def to_json(self) -> str:
        """JSON text (NaN as null)."""
        doc = asdict(self)
        for name in ("design_kpi", "completion_rate"):
            doc[name] = _finite_or_none(doc[name])
        for name in ("hour_design_kpi", "hour_cost_cny"):
            doc[name] = [_finite_or_none(v) for v in doc[name]]
        return json.dumps(doc, separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_json(cls, text: str) -> DayResult:
        """Inverse of ``to_json``."""
        d = json.loads(text)

        def num(v: float | None) -> float:
            return float("nan") if v is None else float(v)

        return cls(
            key=str(d["key"]),
            size=int(d["size"]),
            date=str(d["date"]),
            n_requests=int(d["n_requests"]),
            design_kpi=num(d["design_kpi"]),
            completion_rate=num(d["completion_rate"]),
            hour_design_kpi=tuple(num(v) for v in d["hour_design_kpi"]),
            hour_cost_cny=tuple(num(v) for v in d["hour_cost_cny"]),
            elapsed_s=float(d["elapsed_s"]),
        )


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def run_day(job: DayJob) -> DayResult:
    """Simulate one whole day in this process (top level, so a process pool can call it)."""
    started = time.perf_counter()
    city, trace = run_spec(job.spec, job.demand)
    k = run_kpis(city, trace)
    return DayResult(
        key=job.key,
        size=job.spec.n1,
        date=str(trace.demand["date"]),
        n_requests=len(trace.riders) + trace.n_unposted,
        design_kpi=float(k.design_kpi),
        completion_rate=float(k.completion_rate),
        hour_design_kpi=tuple(float(h.design_kpi) for h in k.hours),
        hour_cost_cny=tuple(float(h.monitoring_cost_cny) for h in k.hours),
        elapsed_s=time.perf_counter() - started,
    )


RunFn = Callable[[DayJob], DayResult]


@dataclass(frozen=True, slots=True)
class RunBatch:
    """The outcome of a batch: results and failures by job key, how many came from the cache."""

    results: dict[str, DayResult]
    failures: dict[str, str] = field(default_factory=dict)
    cached: int = 0
    wall_s: float = 0.0


class DayRunner(Protocol):
    """Runs a batch of whole-day jobs (``PoolRunner``; tests may wrap it)."""

    jobs: int

    def run(self, jobs: Sequence[DayJob]) -> RunBatch: ...

    def close(self) -> None: ...


class RunCache:
    """Finished runs as ``<dir>/<key>.json`` (written to a temporary file, then renamed)."""

    def __init__(self, directory: Path) -> None:
        """Cache under ``directory`` (created on the first write)."""
        self.directory = directory

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.json"

    def get(self, key: str) -> DayResult | None:
        """The cached run, or ``None`` (an unreadable file counts as missing and is logged)."""
        path = self._path(key)
        try:
            return DayResult.from_json(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("ignoring unreadable cached run %s: %r", path, exc)
            return None

    def put(self, result: DayResult) -> None:
        """Store a run atomically."""
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self._path(result.key)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(result.to_json(), encoding="utf-8")
        tmp.replace(path)


class PoolRunner:
    """Runs jobs over ``jobs`` processes (in this process when ``jobs == 1``), reading and filling a cache.

    The process pool (forkserver, like ``app.experiment.runner``) is started on the first batch that needs
    it and kept for later ones; a broken pool is dropped and started again next time.
    """

    def __init__(self, cache: RunCache, jobs: int = 2, run_fn: RunFn = run_day) -> None:
        """``run_fn`` must be a module-level function when ``jobs > 1`` (it is sent to the processes)."""
        if jobs < 1:
            raise ValueError(f"jobs must be at least 1, got {jobs}")
        self.cache = cache
        self.jobs = jobs
        self.run_fn = run_fn
        self._pool: ProcessPoolExecutor | None = None

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            ctx = multiprocessing.get_context("forkserver")
            self._pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx)
        return self._pool

    def run(self, jobs: Sequence[DayJob]) -> RunBatch:
        """Every job's result (cached or computed) or the reason it failed."""
        started = time.perf_counter()
        unique = list({j.key: j for j in jobs}.values())
        results: dict[str, DayResult] = {}
        failures: dict[str, str] = {}
        todo: list[DayJob] = []
        for job in unique:
            hit = self.cache.get(job.key)
            if hit is not None:
                results[job.key] = hit
            else:
                todo.append(job)
        cached = len(results)
        # the largest fleets first: they take longest, so the processes finish together
        todo.sort(key=lambda j: j.spec.n1, reverse=True)
        if self.jobs == 1 or len(todo) <= 1:
            for job in todo:
                self._one(job, results, failures)
        elif todo:
            self._pooled(todo, results, failures)
        return RunBatch(results, failures, cached, time.perf_counter() - started)

    def _one(self, job: DayJob, results: dict[str, DayResult], failures: dict[str, str]) -> None:
        try:
            result = self.run_fn(job)
        except Exception as exc:  # noqa: BLE001 - one failed run is reported, the others go on
            failures[job.key] = f"{type(exc).__name__}: {exc}"
            return
        self.cache.put(result)
        results[job.key] = result

    def _pooled(self, todo: list[DayJob], results: dict[str, DayResult], failures: dict[str, str]) -> None:
        pool = self._executor()
        futures: dict[Future[DayResult], DayJob] = {pool.submit(self.run_fn, j): j for j in todo}
        wait(futures)
        broken = False
        for fut, job in futures.items():
            try:
                result = fut.result()
            except BrokenProcessPool as exc:
                broken = True
                failures[job.key] = f"BrokenProcessPool: {exc}"
                continue
            except Exception as exc:  # noqa: BLE001 - as in _one
                failures[job.key] = f"{type(exc).__name__}: {exc}"
                continue
            self.cache.put(result)
            results[job.key] = result
        if broken:
            self.close()

    def close(self) -> None:
        """Stop the processes."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
