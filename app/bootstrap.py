"""Composition root: ``create_app(settings, registry=None, store=None)`` wires cities, store and API."""

from __future__ import annotations

import functools
import gc
import logging
import subprocess
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager, nullcontext
from typing import Any

from fastapi import FastAPI
from fastapi.routing import APIRoute
from starlette.types import ASGIApp

from app.adapters.bounded import BoundedStore
from app.adapters.cities import CityRegistry
from app.api import admin, cities, dashboard, dispatch, dro, epochs, fleet, ops
from app.api.bodies import openapi_components
from app.api.handlers import error_response, install_error_handlers
from app.api.inputs import Limits
from app.api.limits import BodyLimit
from app.errors import ServiceError
from app.metrics import Metrics
from app.ports import Store
from app.runs.executor import Foreground
from app.schemas.dispatch import read_epoch, render_epoch
from app.settings import Settings
from app.usecases import CityCatalog, DecideFn, EpochLimits, SizingConfig, UseCases

__all__ = ["create_app", "make_store", "API_VERSION"]

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
    if settings.store == "redis":
        from app.adapters.redis_store import RedisStore

        return RedisStore(
            settings.redis_url,
            prefix=settings.redis_prefix,
            socket_timeout_s=settings.store_timeout_s,
            mode=settings.redis_mode,
        )
    from app.adapters.memory_store import MemoryStore

    return MemoryStore()


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
        retention_s=settings.retention_s,
        commit_attempts=settings.commit_attempts,
        max_solves=settings.max_solves,
        solve_queue_s=settings.solve_queue_s,
        max_ahead_s=settings.epoch_max_ahead_s,
    )
    return UseCases.over(
        registry,
        store,
        decide or _default_decide(settings.dispatch_workers),
        render_epoch=render_epoch,
        read_epoch=read_epoch,
        limits=limits,
        worker_stale_s=settings.worker_stale_s,
        sizing=SizingConfig.from_settings(settings),
        clock=time.time if clock is None else clock,
        foreground=nullcontext if foreground is None else foreground.epoch,
    )


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
    the cities are warm). ``embed_worker`` runs the fleet worker in this process for the app's lifetime,
    on the same store (``app.worker.embedded``; its first pass waits for the warm-up). ``compile_apart`` (the
    ``run`` command's too) compiles the kernels in a child process before the warm-up (``_compile_apart``)."""
    settings = settings or Settings()
    owns_store = store is None
    raw_store = store if store is not None else make_store(settings)
    the_store = BoundedStore(raw_store, settings.store_concurrency, settings.store_queue_s)
    the_registry = registry if registry is not None else CityRegistry.from_settings(settings)
    metrics = Metrics()
    foreground = Foreground() if embed_worker else None  # epochs pause the embedded worker's runs
    use_cases = _use_cases(settings, the_registry, the_store, decide, clock, foreground)

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        # load and warm the cities in the background; /readyz answers 503 until that has finished, so a
        # balancer sends no epoch that would wait for the kernels to compile
        if tune_gc:
            gc.set_threshold(*GC_THRESHOLD)
        warmed = threading.Event()
        use_cases.readiness.warming = warmed
        threading.Thread(
            target=_warm,
            args=(the_registry, tune_gc, warmed, compile_apart),
            name="warm-cities",
            daemon=True,
        ).start()
        worker = None
        if embed_worker:
            from app.worker.embedded import EmbeddedWorker

            worker = EmbeddedWorker(settings, raw_store, the_registry, ready=warmed, foreground=foreground)
            worker.start()
        try:
            yield
        finally:
            if worker is not None:
                worker.stop()
            if owns_store:
                the_store.close()

    app = FastAPI(
        title="sensedispatch",
        version=API_VERSION,
        description=_DESCRIPTION,
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
    )
    app.state.settings = settings
    app.state.use_cases = use_cases
    app.state.metrics = metrics
    install_error_handlers(app, metrics)

    def render(err: ServiceError) -> ASGIApp:
        return error_response(err, metrics)

    app.add_middleware(
        BodyLimit, max_bytes=settings.max_body_bytes, timeout_s=settings.body_timeout_s, render=render
    )
    app.include_router(ops.router)
    app.include_router(cities.router)
    app.include_router(dispatch.router)
    app.include_router(dro.router)
    app.include_router(fleet.router)
    app.include_router(epochs.router)
    app.include_router(admin.router)
    app.include_router(dashboard.router)
    dashboard.mount_assets(app)
    _declare_request_bodies(app, Limits.from_settings(settings))
    return app


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


GC_THRESHOLD = (10_000, 10, 10)
"""The collector's thresholds in the service process (Python's default is (700, 10, 10)). An epoch allocates
hundreds of thousands of short-lived objects (a Manhattan epoch's response alone is 0.5 MB of JSON built from
dicts), so at 700 the young generations were collected ~45 times an epoch and the whole heap every few
epochs; docs/DESIGN.md ("Speed without changing a decision") and docs/PERFORMANCE.md have the measurements."""


def _warm_bundle(directory: str) -> None:
    """In a child process: warm up the city bundle in ``directory`` (``_compile_apart``)."""
    from services.citydata import load_city
    from services.dispatch import warm_up

    warm_up(load_city(directory))


def _compile_apart(registry: CityCatalog) -> str | None:
    """Compile every kernel an epoch calls in a child process, by warming the smallest served city there:
    numba writes what it compiles to its on-disk cache, and this process's warm-up then loads the kernels
    from there. Compiling (LLVM) holds memory that the process keeps for its lifetime: about 360 MB more
    than loading the same kernels from the cache (docs/PERFORMANCE.md, "Memory of the service"), which a
    fresh install would otherwise carry in the service for good. With the cache already filled the child
    only reads it (a few seconds). A child that fails is logged; the warm-up then compiles here. The name
    of the city warmed in the child, ``None`` when it failed or no bundle is served."""
    if not isinstance(registry, CityRegistry) or not registry.names():
        return None
    bundles = [registry.bundle_dir(name) for name in registry.names()]
    smallest = min(bundles, key=lambda d: (d / "network.npz").stat().st_size)
    began = time.perf_counter()
    code = f"from app.bootstrap import _warm_bundle; _warm_bundle({str(smallest)!r})"
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if child.returncode != 0:
        log.warning(
            "compiling the kernels in a child process failed (exit %s): %s",
            child.returncode,
            child.stderr[-2000:],
        )
        return None
    log.info("kernels compiled apart (warming %s) in %.1f s", smallest.name, time.perf_counter() - began)
    return smallest.name


def _warm(
    registry: CityCatalog,
    freeze: bool = False,
    done: threading.Event | None = None,
    compile_apart: bool = False,
) -> None:
    """Load every city once and warm it up (``services.dispatch.warm_up``), so that every kernel is compiled
    (or loaded from cache) and each city's search structures (road graph, landmark table) built before its
    first epoch arrives (errors surface later, per request and in /readyz). With ``freeze``, what start-up
    built (the cities, the app, the compiled kernels' Python objects) is then moved out of the collector's
    reach (``gc.freeze``): it lives as long as the process, and scanning it made each full collection
    ~100 ms at Manhattan scale. ``done`` is set at the end, whatever happened (a city that failed to load
    is /readyz's to report). With ``compile_apart`` the kernels are compiled in a child first."""
    from services.dispatch import warm_up

    began = time.perf_counter()
    try:
        if compile_apart:
            try:
                _compile_apart(registry)
            except Exception:
                log.exception("compiling the kernels in a child process failed")
        for name in registry.names():
            try:
                warm_up(registry.get(name))
            except Exception:
                log.exception("city %s failed to load", name)
        log.info("warm-up finished in %.1f s: ready", time.perf_counter() - began)
        if freeze:
            gc.collect()
            gc.freeze()
    finally:
        if done is not None:
            done.set()
