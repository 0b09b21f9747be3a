"""One fleet worker put together from the settings: its runner (run cache and executor), sizing, loop,
metrics and heartbeat. ``python -m app worker`` and the worker embedded in ``python -m app run``
(``app.worker.embedded``) are built the same way."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass

from app.adapters.cities import CityRegistry
from app.ports import Store
from app.runs import ProcessExecutor, Progress, ResultCache, RunCache, Runner, make_executor
from app.runs.executor import Foreground
from app.schemas.fleet import render_recommendation
from app.settings import Settings
from app.usecases.fleet_history import SizingConfig
from app.usecases.fleet_solve import FleetSolver
from app.worker.heartbeat import Heartbeat, WorkerStatus
from app.worker.service import FleetWorker, WorkerMetrics

__all__ = ["make_runner", "worker_cities", "AssembledWorker", "assemble_worker"]


def make_runner(settings: Settings, *, in_process: bool = True) -> Runner:
    """The runner the settings describe: its run cache (disk or Redis) and its executor. With
    ``in_process`` False the runs never execute in this process (one local process at least): the API's
    embedded worker keeps the simulations out of the process that answers epochs."""
    cache: ResultCache
    if settings.run_cache_kind() == "redis":
        from app.adapters.redis_client import redis_client
        from app.adapters.run_cache import RedisRunCache

        client = redis_client(settings.redis_url)
        cache = RedisRunCache(client, settings.redis_prefix, ttl_s=settings.retention_s)
    else:
        cache = RunCache(settings.var_dir / "fleet-runs")
    executor = make_executor(
        settings.worker_jobs,
        settings.worker_executor,
        scheduler=settings.dask_scheduler,
        timeout_s=settings.dask_timeout_s,
        nice=settings.worker_nice,
        in_process=in_process,
    )
    return Runner(cache, executor)


def worker_cities(settings: Settings, registry: CityRegistry) -> tuple[list[str], list[str]]:
    """The cities the worker sizes (``SD_WORKER_CITIES``, default every served city) and, sorted, those of
    them the registry does not serve (a worker is not started with any)."""
    known = registry.names()
    cities = settings.worker_cities or known
    return cities, sorted(set(cities) - set(known))


@dataclass(frozen=True, slots=True)
class AssembledWorker:
    """A worker's parts: the loop, its heartbeat (not started), the runner to close, its metrics."""

    worker: FleetWorker
    heartbeat: Heartbeat
    runner: Runner
    metrics: WorkerMetrics

    def serve(self, stop: threading.Event) -> None:
        """Beat and run the loop until ``stop`` is set; then stop beating (the runner stays open)."""
        self.heartbeat.start()
        try:
            self.worker.run(stop)
        finally:
            self.heartbeat.stop()


def assemble_worker(
    settings: Settings,
    store: Store,
    registry: CityRegistry,
    cities: Sequence[str],
    *,
    embedded: bool,
    foreground: Foreground | None = None,
) -> AssembledWorker:
    """The worker of ``cities`` on ``store``, as the settings configure it (``embedded``: inside the API
    process, its runs on local processes whatever ``SD_WORKER_JOBS`` says, paused by ``foreground`` while
    the API solves an epoch)."""
    runner = make_runner(settings, in_process=not embedded)
    if foreground is not None and isinstance(runner.executor, ProcessExecutor):
        foreground.add(runner.executor)
    metrics = WorkerMetrics()
    status = WorkerStatus(embedded=embedded, poll_s=settings.worker_poll_s)

    def progress(p: Progress) -> None:
        metrics.progress(p)
        status.progress(p)

    sizing = FleetSolver(
        store,
        runner,
        SizingConfig.from_settings(settings),
        render=render_recommendation,
        cities=registry,
        progress=progress,
        history_limit=settings.worker_history,
        lock_ttl_s=float(settings.worker_lock_ttl_s),
    )
    worker = FleetWorker(
        sizing,
        cities,
        lead_s=settings.worker_lead_s,
        poll_s=settings.worker_poll_s,
        metrics=metrics,
        status=status,
    )
    heartbeat = Heartbeat(sizing, status, cities, interval_s=settings.worker_heartbeat_s)
    return AssembledWorker(worker, heartbeat, runner, metrics)
