"""The API process's start-up: every served city loaded and warmed before ``/readyz`` says ready (the
kernels compiled, or loaded from numba's cache, in a child process first), and the garbage collector set for
a long-lived heap. ``app.bootstrap.create_app``'s lifespan runs ``warm`` on a thread."""

from __future__ import annotations

import gc
import logging
import subprocess
import sys
import threading
import time

from app.usecases import CityCatalog
from app.usecases.fleet_solve import BundleCatalog

__all__ = ["GC_THRESHOLD", "warm", "compile_apart"]

log = logging.getLogger(__name__)


GC_THRESHOLD = (10_000, 10, 10)
"""The collector's thresholds in the service process (Python's default is (700, 10, 10)). An epoch allocates
hundreds of thousands of short-lived objects (a Manhattan epoch's response alone is 0.5 MB of JSON built from
dicts), so at 700 the young generations were collected ~45 times an epoch and the whole heap every few
epochs; docs/DESIGN.md ("Speed without changing a decision") and docs/PERFORMANCE.md have the measurements."""


def _warm_bundle(directory: str) -> None:
    """In a child process: warm up the city bundle in ``directory`` (``compile_apart``)."""
    from services.citydata import load_city
    from services.dispatch import warm_up

    warm_up(load_city(directory))


def compile_apart(registry: CityCatalog) -> str | None:
    """Compile every kernel an epoch calls in a child process, by warming the smallest served city there:
    numba writes what it compiles to its on-disk cache, and this process's warm-up then loads the kernels
    from there. Compiling (LLVM) holds memory that the process keeps for its lifetime: about 360 MB more
    than loading the same kernels from the cache (docs/PERFORMANCE.md, "Memory of the service"), which a
    fresh install would otherwise carry in the service for good. With the cache already filled the child
    only reads it (a few seconds). A child that fails is logged; the warm-up then compiles here. The name
    of the city warmed in the child, ``None`` when it failed or no bundle is served."""
    if not isinstance(registry, BundleCatalog) or not registry.names():
        return None
    bundles = [registry.bundle_dir(name) for name in registry.names()]
    smallest = min(bundles, key=lambda d: (d / "network.npz").stat().st_size)
    began = time.perf_counter()
    code = f"from app.api.warmup import _warm_bundle; _warm_bundle({str(smallest)!r})"
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


def _prune_kernel_caches() -> None:
    """Remove the compiled kernels of other sources left on disk by earlier versions
    (``services.kernel.jit.prune_stale``), and say so."""
    import numba

    from services.kernel.jit import prune_stale

    removed = prune_stale(numba.config.CACHE_DIR)  # type: ignore[attr-defined]
    if removed:
        mb = sum(size for _, size in removed) / 1e6
        log.info("removed %d stale kernel cache directories (%.1f MB)", len(removed), mb)


def warm(
    registry: CityCatalog,
    freeze: bool = False,
    done: threading.Event | None = None,
    apart: bool = False,
) -> None:
    """Load every city once and warm it up (``services.dispatch.warm_up``), so that every kernel is compiled
    (or loaded from cache) and each city's search structures (road graph, landmark table) built before its
    first epoch arrives (errors surface later, per request and in /readyz). With ``freeze``, what start-up
    built (the cities, the app, the compiled kernels' Python objects) is then moved out of the collector's
    reach (``gc.freeze``): it lives as long as the process, and scanning it made each full collection
    ~100 ms at Manhattan scale. ``done`` is set at the end, whatever happened (a city that failed to load
    is /readyz's to report). With ``apart`` the kernels are compiled in a child first (``compile_apart``),
    after the kernel caches of other sources untouched for a day are removed (``_prune_kernel_caches``)."""
    from services.dispatch import warm_up

    began = time.perf_counter()
    try:
        if apart:
            _prune_kernel_caches()
            try:
                compile_apart(registry)
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
