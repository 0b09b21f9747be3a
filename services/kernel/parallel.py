"""Independent searches of one epoch run side by side on a few threads (the compiled kernels release the
GIL). The number of threads is the caller's (``decide(..., workers=...)``, from the service's settings);
results come back in input order, so a decision does not depend on it."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

__all__ = ["parallel_map", "default_workers"]

_T = TypeVar("_T")
_R = TypeVar("_R")

_pools: dict[tuple[int, int], ThreadPoolExecutor] = {}  # (threads, pid) -> pool; a forked child makes its own
_lock = threading.Lock()


def default_workers() -> int:
    """The CPUs this process may use, at most 4."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    return max(1, min(4, cpus))


def _pool(workers: int) -> ThreadPoolExecutor:
    key = (workers, os.getpid())
    with _lock:
        pool = _pools.get(key)
        if pool is None:
            pool = _pools[key] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="sd-search")
        return pool


def parallel_map(fn: Callable[[Sequence[_T]], list[_R]], items: Sequence[_T], workers: int) -> list[_R]:
    """``fn(items)`` computed as ``fn`` over contiguous chunks of ``items`` on ``workers`` threads,
    concatenated in order. ``fn`` maps a chunk to one result per item and must not call ``parallel_map``.
    The first exception (in item order) is raised, as one call over all items would."""
    if workers <= 1 or len(items) < 2:
        return fn(items)
    n_chunks = min(len(items), 4 * workers)
    bounds = [len(items) * i // n_chunks for i in range(n_chunks + 1)]
    pool = _pool(workers)
    futures = [pool.submit(fn, items[a:b]) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    out: list[_R] = []
    for f in futures:
        out.extend(f.result())
    return out
