"""The composition root: every process's parts built from the settings, here and nowhere else.

- ``make_store``: the store the settings ask for (memory or Redis);
- ``create_app``: the API (use cases over the store, routers, error handlers, body limits), with the cities
  warmed in its lifespan (``app.api.warmup``) and, when asked, the fleet worker embedded;
- ``build_worker``: the fleet worker (runner with its run cache and executor, the solve use case, loop,
  metrics, heartbeat), for ``python -m app worker`` and for the worker the API embeds (``embedded_worker``).

The entry points (``app.entrypoints``) read their options and ask for these; nothing else wires a store to
a use case.
"""

from __future__ import annotations

import functools
import gc
import logging
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator, Sequence
from contextlib import (
    AbstractAsyncContextManager,
    AbstractContextManager,
    asynccontextmanager,
    contextmanager,
    nullcontext,
)
from typing import Any

from fastapi import FastAPI
from fastapi.routing import APIRoute
from starlette.types import ASGIApp

from app.adapters.bounded import BoundedStore
from app.adapters.city_registry import CityRegistry
from app.api import admin, cities, dashboard, dro, epochs, fleet, ops, writes
from app.api.bodies import openapi_components
from app.api.collector import CollectorDeferral
from app.api.deps import token_scopes
from app.api.foreground import EpochForeground
from app.api.handlers import error_response, install_error_handlers
from app.api.inputs import Limits
from app.api.limits import BodyLimit
from app.api.warmup import GC_THRESHOLD, warm
from app.errors import ServiceError
from app.metrics import Metrics
from app.ports import Store
from app.runs import ProcessExecutor, Progress, ResultCache, RunCache, Runner, make_executor
from app.runs.executor import Foreground
from app.schemas.fleet import render_recommendation
from app.settings import Settings
from app.usecases import CityCatalog, DecideFn, EpochLimits, SizingConfig, UseCases
from app.usecases.fleet_solve import BundleCatalog, FleetSolver
from app.worker.embedded import EmbeddedWorker
from app.worker.heartbeat import Heartbeat, WorkerStatus
from app.worker.service import AssembledWorker, FleetWorker, WorkerMetrics

__all__ = [
    "API_VERSION",
    "create_app",
    "make_store",
    "make_runner",
    "worker_cities",
    "build_worker",
    "embedded_worker",
]

log = logging.getLogger(__name__)

API_VERSION = "1.0.0"

_DESCRIPTION = """\
Online dispatch for ride-hailing fleets that do drive-by sensing: every decision epoch the platform posts
waiting riders and taxis; the service answers with a three-step priority matching (instrumented taxis
first, by sensing gain), sensing-aware monitoring routes to points of interest, and keeps the grid counts
of distinct instrumented vehicles per cell and interval, committing every epoch exactly once.

Errors always have the shape `{"error": kind, "detail": text, "fields": [{"loc", "msg"}]}`.
"""


def make_store(settings: Settings) -> Store:
    """The store the settings ask for."""
    if settings.store.kind == "redis":
        from app.adapters.redis_store import RedisStore

        return RedisStore(
            settings.store.redis_url,
            prefix=settings.store.redis_prefix,
            socket_timeout_s=settings.store.timeout_s,
            mode=settings.store.redis_mode,
        )
    from app.adapters.memory_store import MemoryStore

    return MemoryStore()


# -- the API ---------------------------------------------------------------------------------------------


def _default_decide(workers: int) -> DecideFn:
    from services.dispatch import decide

    return functools.partial(decide, workers=workers)


def _use_cases(
    settings: Settings,
    registry: CityCatalog,
    store: Store,
    decide: DecideFn | None,
    clock: Callable[[], float] | None,
    foreground: Foreground | None,
) -> UseCases:
    """The use cases over ``store``, with the settings' limits (``foreground``: the embedded worker's)."""
    limits = EpochLimits(
        retention_s=settings.store.retention_s,
        commit_attempts=settings.dispatch.commit_attempts,
        max_solves=settings.dispatch.max_solves,
        solve_queue_s=settings.dispatch.solve_queue_s,
        max_ahead_s=settings.dispatch.epoch_max_ahead_s,
    )
    return UseCases.over(
        registry,
        store,
        decide or _default_decide(settings.dispatch.workers),
        limits=limits,
        worker_stale_s=settings.worker.stale_s,
        sizing=SizingConfig.from_settings(settings.sizing, settings.store.retention_s),
        clock=time.time if clock is None else clock,
        foreground=nullcontext if foreground is None else foreground.epoch,
    )


def _epoch_exchange(
    use_cases: UseCases, deferral: CollectorDeferral | None
) -> Callable[[], AbstractContextManager[None]]:
    """What an epoch post holds for its whole exchange: the use cases' current foreground, and the
    collector kept off (``deferral``) when there is one."""

    @contextmanager
    def exchange() -> Iterator[None]:
        with use_cases.epochs.foreground(), deferral.held() if deferral is not None else nullcontext():
            yield

    return exchange


def create_app(
    settings: Settings | None = None,
    registry: CityCatalog | None = None,
    store: Store | None = None,
    *,
    decide: DecideFn | None = None,
    clock: Callable[[], float] | None = None,
    tune_gc: bool = False,
    embed_worker: bool = False,
    compile_apart: bool = False,
) -> FastAPI:
    """Build the FastAPI app; a store passed in is the caller's to close, one built here is closed here.
    ``clock`` (POSIX seconds, default ``time.time``) is the service clock of the epoch time window and of
    the fleet worker's heartbeats. ``tune_gc`` (the ``run`` command's: the process is the service's alone)
    sets the garbage collector for a long-lived heap (``GC_THRESHOLD``, and start-up's objects frozen once
    the cities are warm) and keeps it off during epoch exchanges (``app.api.collector``). ``embed_worker``
    runs the fleet worker in this process for the app's lifetime, on the same store (``embedded_worker``;
    its first pass waits for the warm-up). ``compile_apart`` (the ``run`` command's too) compiles the
    kernels in a child process before the warm-up (``app.api.warmup.compile_apart``)."""
    settings = settings or Settings()
    raw_store = store if store is not None else make_store(settings)
    the_store = BoundedStore(raw_store, settings.store.concurrency, settings.store.queue_s)
    the_registry = registry if registry is not None else CityRegistry.from_settings(settings)
    metrics = Metrics()
    foreground = Foreground() if embed_worker else None  # epochs pause the embedded worker's runs
    use_cases = _use_cases(settings, the_registry, the_store, decide, clock, foreground)

    def start(warmed: threading.Event) -> EmbeddedWorker | None:
        """Warm the cities on a thread; start the embedded worker (it waits for ``warmed``)."""
        if tune_gc:
            gc.set_threshold(*GC_THRESHOLD)
        use_cases.readiness.warming = warmed
        threading.Thread(
            target=warm,
            args=(the_registry, tune_gc, warmed, compile_apart),
            name="warm-cities",
            daemon=True,
        ).start()
        if not embed_worker:
            return None
        return embedded_worker(settings, raw_store, the_registry, ready=warmed, foreground=foreground)

    app = FastAPI(
        title="sensedispatch",
        version=API_VERSION,
        description=_DESCRIPTION,
        lifespan=_lifespan(start, the_store if store is None else None),
        generate_unique_id_function=_operation_id,
    )
    app.state.settings = settings
    app.state.use_cases = use_cases
    app.state.metrics = metrics
    install_error_handlers(app, metrics)

    def render(err: ServiceError) -> ASGIApp:
        return error_response(err, metrics)

    app.add_middleware(
        BodyLimit,
        max_bytes=settings.server.max_body_bytes,
        timeout_s=settings.server.body_timeout_s,
        render=render,
    )
    # outermost: an epoch post that may dispatch holds the foreground from its headers on, body included,
    # and (in the service's own process) keeps the collector's passes for after its response
    app.add_middleware(
        EpochForeground,
        hold=_epoch_exchange(use_cases, CollectorDeferral() if tune_gc else None),
        dispatches=lambda token: "dispatch" in (token_scopes(settings, token) or ()),
    )
    for router in (ops, cities, writes, dro, fleet, epochs, admin, dashboard):
        app.include_router(router.router)
    dashboard.mount_assets(app)
    _declare_request_bodies(app, Limits.from_settings(settings))
    return app


def _lifespan(
    start: Callable[[threading.Event], EmbeddedWorker | None], owned: BoundedStore | None
) -> Callable[[FastAPI], AbstractAsyncContextManager[None]]:
    """The app's lifespan: ``start`` (the warm-up in the background: /readyz answers 503 until it has
    finished, so a balancer sends no epoch that would wait for the kernels to compile; the embedded worker)
    at start-up; at shutdown the worker stopped and the ``owned`` store closed."""

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        worker = start(threading.Event())
        try:
            yield
        finally:
            if worker is not None:
                worker.stop()
            if owned is not None:
                owned.close()

    return lifespan


def _declare_request_bodies(app: FastAPI, limits: Limits) -> None:
    """Add the request bodies' schemas (read off the event loop by ``app.api.bodies``, so FastAPI does not
    see them) to the document's components, with the configured array limits."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            doc = build()
            doc.setdefault("components", {}).setdefault("schemas", {}).update(openapi_components(limits))
            app.openapi_schema = doc
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _operation_id(route: APIRoute) -> str:
    """Operation ids are the endpoint function names (``post_epoch``), stable for client generators."""
    return route.name


# -- the fleet worker ------------------------------------------------------------------------------------


def make_runner(settings: Settings, *, in_process: bool = True) -> Runner:
    """The runner the settings describe: its run cache (disk or Redis) and its executor. With
    ``in_process`` False the runs never execute in this process (one local process at least): the API's
    embedded worker keeps the simulations out of the process that answers epochs."""
    cache: ResultCache
    if settings.run_cache_kind() == "redis":
        from app.adapters.redis_client import redis_client
        from app.adapters.run_cache import RedisRunCache

        client = redis_client(settings.store.redis_url)
        cache = RedisRunCache(client, settings.store.redis_prefix, ttl_s=settings.store.retention_s)
    else:
        cache = RunCache(settings.runs.var_dir / "fleet-runs")
    executor = make_executor(
        settings.runs.jobs,
        settings.runs.executor,
        scheduler=settings.runs.dask_scheduler,
        timeout_s=settings.runs.dask_timeout_s,
        nice=settings.runs.nice,
        in_process=in_process,
    )
    return Runner(cache, executor)


def worker_cities(settings: Settings, registry: CityCatalog) -> tuple[list[str], list[str]]:
    """The cities the worker sizes (``SD_WORKER_CITIES``, default every served city) and, sorted, those of
    them the registry does not serve (a worker is not started with any)."""
    known = registry.names()
    cities = settings.worker.cities or known
    return cities, sorted(set(cities) - set(known))


def build_worker(
    settings: Settings,
    store: Store,
    registry: BundleCatalog,
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
    status = WorkerStatus(embedded=embedded, poll_s=settings.worker.poll_s)

    def progress(p: Progress) -> None:
        metrics.progress(p)
        status.progress(p)

    sizing = FleetSolver(
        store,
        runner,
        SizingConfig.from_settings(settings.sizing, settings.store.retention_s),
        render=render_recommendation,
        cities=registry,
        progress=progress,
        history_limit=settings.worker.history,
        lock_ttl_s=float(settings.worker.lock_ttl_s),
    )
    worker = FleetWorker(
        sizing,
        cities,
        lead_s=settings.worker.lead_s,
        poll_s=settings.worker.poll_s,
        metrics=metrics,
        status=status,
    )
    heartbeat = Heartbeat(sizing, status, cities, interval_s=settings.worker.heartbeat_s)
    return AssembledWorker(worker, heartbeat, runner, metrics)


def embedded_worker(
    settings: Settings,
    store: Store,
    registry: CityCatalog,
    *,
    ready: threading.Event | None = None,
    foreground: Foreground | None = None,
) -> EmbeddedWorker | None:
    """The fleet worker inside the API process, started: beating at once, solving once ``ready`` is set
    (the warm-up is over), its runs paused by ``foreground`` while an epoch is solved. ``registry`` serves
    the cities (a ``CityRegistry`` also gives the bundles the runs read; any other catalog is replaced by
    the settings' registry). An unknown city in SD_WORKER_CITIES is logged and no worker starts (``None``:
    the API then answers solve requests with 503 no_worker)."""
    bundles = registry if isinstance(registry, BundleCatalog) else CityRegistry.from_settings(settings)
    cities, unknown = worker_cities(settings, bundles)
    if unknown:
        log.error(
            "fleet worker not started: unknown cities %s in SD_WORKER_CITIES; served: %s",
            unknown,
            bundles.names(),
        )
        return None
    parts = build_worker(settings, store, bundles, cities, embedded=True, foreground=foreground)
    worker = EmbeddedWorker(parts, ready=ready)
    worker.start()
    log.info(
        "fleet worker running in this process for %s (simulation runs on %d local process(es) at "
        "niceness +%d)",
        ", ".join(cities),
        max(1, settings.runs.jobs),
        settings.runs.nice,
    )
    return worker
