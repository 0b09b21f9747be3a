"""Scratch memory for the searches of an epoch: one pad per thread, taken and given back around a chunk of
work. The pads of a city's graph are kept from epoch to epoch (``pads_for``), so the workspaces are
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

__all__ = ["Pad", "Pads", "pads_for"]


class Pad:
    """A forward and a reverse search workspace, and room for other scratch (``extra``, by key)."""

    def __init__(self, graph: RoadGraph) -> None:
        self.graph = graph
        self.forward = heaps.workspace(graph)
        self.reverse = heaps.workspace(graph, reverse=True)
        self.extra: dict[object, object] = {}


class Pads:
    """Pads for ``graph``, made on first need; ``take`` lends one to the calling thread. ``parallel_map``
    runs at most ``workers`` chunks at once, so an epoch makes at most that many."""

    def __init__(self, graph: RoadGraph) -> None:
        self.graph = graph
        self._free: queue.SimpleQueue[Pad] = queue.SimpleQueue()

    @contextmanager
    def take(self) -> Iterator[Pad]:
        try:
            pad = self._free.get_nowait()
        except queue.Empty:
            pad = Pad(self.graph)
        try:
            yield pad
        finally:
            self._free.put(pad)


_by_graph: weakref.WeakKeyDictionary[RoadGraph, Pads] = weakref.WeakKeyDictionary()
_lock = threading.Lock()


def pads_for(graph: RoadGraph) -> Pads:
    """The pads of ``graph``, kept while the graph lives (decisions do not depend on them: a search resets
    what it reads)."""
    with _lock:
        pads = _by_graph.get(graph)
        if pads is None:
            pads = _by_graph[graph] = Pads(graph)
        return pads
