"""Scratch memory for the searches of an epoch: one ``Scratch`` per thread, taken from the graph's
``ScratchPool`` and given back around a chunk of work. The pool of a city's graph is kept from epoch to epoch
(``scratch_pool``), so the workspaces are
allocated once per concurrent chunk for the life of the process, not once per search or per epoch: large
fresh arrays page fault, which at metropolitan size costs as much as the search."""

from __future__ import annotations

import queue
import threading
import weakref
from collections.abc import Iterator
from contextlib import contextmanager

from services.network import heaps
from services.network.graph import RoadGraph

__all__ = ["Scratch", "ScratchPool", "scratch_pool"]


class Scratch:
    """A forward and a reverse search workspace, and room for other scratch (``extra``, by key)."""

    def __init__(self, graph: RoadGraph) -> None:
        self.graph = graph
        self.forward = heaps.workspace(graph)
        self.reverse = heaps.workspace(graph, reverse=True)
        self.extra: dict[object, object] = {}


class ScratchPool:
    """Scratches for ``graph``, made on first need; ``take`` lends one to the calling thread. ``parallel_map``
    runs at most ``workers`` chunks at once, so an epoch makes at most that many."""

    def __init__(self, graph: RoadGraph) -> None:
        self.graph = graph
        self._free: queue.SimpleQueue[Scratch] = queue.SimpleQueue()

    @contextmanager
    def take(self) -> Iterator[Scratch]:
        try:
            scratch = self._free.get_nowait()
        except queue.Empty:
            scratch = Scratch(self.graph)
        try:
            yield scratch
        finally:
            self._free.put(scratch)


_by_graph: weakref.WeakKeyDictionary[RoadGraph, ScratchPool] = weakref.WeakKeyDictionary()
_lock = threading.Lock()


def scratch_pool(graph: RoadGraph) -> ScratchPool:
    """The scratch pool of ``graph``, kept while the graph lives (decisions do not depend on it: a search
    resets what it reads)."""
    with _lock:
        pool = _by_graph.get(graph)
        if pool is None:
            pool = _by_graph[graph] = ScratchPool(graph)
        return pool
