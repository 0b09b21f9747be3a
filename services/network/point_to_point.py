"""Canonical fastest paths between given pairs with the landmark-guided search on the contracted graph,
and the landmark table behind its bounds (the "ALT" bounds of Goldberg and Harrelson, 2005) and the
network's crossing time. ``services.network.hierarchy.fastest_paths`` is the front door: these serve
a network without a hierarchy (the same paths).
"""

from __future__ import annotations

import threading
import weakref
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from services.network import stored
from services.network.dijkstra import run
from services.network.graph import (
    INF,
    Costs,
    RoadGraph,
)
from services.network.heaps import Workspace, workspace
from services.network.unfolding import labels, path_to, paths, tree

__all__ = [
    "split_paths",
    "landmark_fastest_paths",
    "fastest_path",
    "path",
    "LANDMARKS",
    "landmarks",
    "landmark_nodes",
    "landmark_table",
    "crossing_us",
]


def split_paths(
    ptr: NDArray[np.int64], flat: NDArray[np.int64], sources: NDArray[np.int64], targets: NDArray[np.int64]
) -> list[NDArray[np.int64]]:
    """The paths of a CSR ``(ptr, flat)`` as ``paths`` returns them, one array each.

    Raises
    ------
    ValueError
        When a pair could not be joined (its ``ptr`` is -1).
    """
    bad = np.flatnonzero(ptr[1:] < 0)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"node {int(targets[i])} cannot be reached from node {int(sources[i])}")
    return [flat[ptr[i] : ptr[i + 1]] for i in range(len(sources))]


def landmark_fastest_paths(
    graph: RoadGraph, workspace: Workspace, sources: NDArray[np.int64], targets: NDArray[np.int64]
) -> list[NDArray[np.int64]]:
    """The canonical fastest path of every (source, target) pair (one compiled call).

    Raises
    ------
    ValueError
        When a target cannot be reached from its source.
    """
    src = np.asarray(sources, dtype=np.int64)
    tgt = np.asarray(targets, dtype=np.int64)
    ptr, flat = paths(graph.forward, graph.edges, graph.time_forward, workspace, src, tgt, landmarks(graph))
    return split_paths(ptr, flat, src, tgt)


def fastest_path(graph: RoadGraph, workspace: Workspace, source: int, target: int) -> NDArray[np.int64]:
    """Edges of the canonical fastest path from ``source`` to ``target`` (forward workspace ``workspace``).

    Raises
    ------
    ValueError
        When ``target`` cannot be reached.
    """
    return path(graph, workspace, graph.time_forward, source, target)


def path(graph: RoadGraph, workspace: Workspace, costs: Costs, source: int, target: int) -> NDArray[np.int64]:
    """Edges of the canonical shortest path from ``source`` to ``target`` under ``costs`` (forward).

    Raises
    ------
    ValueError
        When ``target`` cannot be reached.
    """
    ed = graph.edges
    tgt = np.array([target], dtype=np.int64)
    out = np.zeros(1, dtype=np.int64)
    tree(graph.forward, ed, costs, int(source), int(INF), tgt, tgt, workspace, out)
    if out[0] >= INF:
        raise ValueError(f"node {target} cannot be reached from node {source}")
    edges: NDArray[np.int64] = path_to(ed, 1, workspace.pred, int(source), int(target))
    return edges


LANDMARKS = 8
"""Landmarks per city for the goal-directed point-to-point searches (``landmarks``)."""

_landmarks: weakref.WeakKeyDictionary[RoadGraph, tuple[NDArray[np.int64], NDArray[np.int64]]] = (
    weakref.WeakKeyDictionary()
)
_landmarks_lock = threading.Lock()


def landmarks(graph: RoadGraph, count: int = LANDMARKS) -> NDArray[np.int64]:
    """The travel times between every node and ``count`` landmarks, as ``(n, 2 count)``: column ``i`` from
    the node to landmark ``i``, column ``count + i`` from landmark ``i`` to the node (``INF``: no path);
    built once per graph. Landmarks are picked farthest first (each the node farthest, there and back,
    from the ones before, starting from node 0's farthest), so that for most pairs one lies beyond the
    target and its bound (``_bound``) is close to the true time (the "ALT" bounds of Goldberg and
    Harrelson, 2005). Only speed depends on the choice."""
    return _picked(graph, count)[0]


def landmark_nodes(graph: RoadGraph, count: int = LANDMARKS) -> NDArray[np.int64]:
    """The nodes ``landmarks`` picked, in the order of its columns."""
    return _picked(graph, count)[1]


def _picked(graph: RoadGraph, count: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    count = min(count, graph.n_nodes)
    with _landmarks_lock:
        got = _landmarks.get(graph)
        if got is None or got[1].shape[0] != count:
            got = _landmarks[graph] = _stored_landmarks(graph, count)
        return got


def _stored_landmarks(graph: RoadGraph, count: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``_landmark_table`` read back from ``stored`` when it was built before for the same network, else
    built and stored."""
    ed, n = graph.edges, graph.n_nodes

    def built() -> stored.Arrays:
        table, picked = _landmark_table(graph, count)
        return {"table": table, "picked": picked}

    def fits(arrays: stored.Arrays) -> bool:
        return stored.shaped(arrays, {"table": (np.int64, (n, 2 * count)), "picked": (np.int64, (count,))})

    got = stored.kept("landmarks", (n, count, ed.tail, ed.head, ed.time_us, ed.tie1, ed.tie2), built, fits)
    return np.asarray(got["table"], dtype=np.int64), np.asarray(got["picked"], dtype=np.int64)


def _costs_to_or_from(graph: RoadGraph, costs: Costs, v: int, back: bool, ws: Workspace) -> NDArray[np.int64]:
    """Every node's cost to node ``v`` (a reverse search, ``costs`` prepared for it), or from ``v`` when
    ``back`` (forward); ``INF``: no path. ``ws``: a workspace of that direction."""
    sg = graph.forward if back else graph.reverse
    out = np.empty((3, graph.n_nodes), dtype=np.int64)
    run(sg, graph.edges, costs, v, INF, np.zeros(0, dtype=np.int64), ws)
    labels(sg, graph.edges, costs, INF, np.arange(graph.n_nodes, dtype=np.int64), ws, out)
    costs_of: NDArray[np.int64] = out[0]
    return costs_of


def _landmark_table(graph: RoadGraph, count: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    n = graph.n_nodes
    table = np.full((n, 2 * count), INF, dtype=np.int64)
    picked = np.zeros(count, dtype=np.int64)
    wf, wr = workspace(graph), workspace(graph, reverse=True)

    def there_and_back(v: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        return (
            _costs_to_or_from(graph, graph.time_reverse, v, False, wr),
            _costs_to_or_from(graph, graph.time_forward, v, True, wf),
        )

    to0, from0 = there_and_back(0)
    spread = np.where((to0 < INF) & (from0 < INF), to0 + from0, -1)  # nodes that reach 0 and back
    for i in range(count):
        v = int(np.argmax(spread))
        picked[i] = v
        table[:, i], table[:, count + i] = there_and_back(v)
        there, back = table[:, i], table[:, count + i]
        both = np.where((there < INF) & (back < INF), there + back, -1)
        spread = both if i == 0 else np.minimum(spread, both)
    return table, picked


def landmark_table(
    graph: RoadGraph, at: NDArray[np.int64], forward: Costs, reverse: Costs, workers: int
) -> NDArray[np.int64]:
    """``landmarks``' table for the landmarks ``at`` under the metric prepared as ``forward`` and
    ``reverse`` (its ``_bound`` is then a lower bound on that metric, and on any metric no cheaper on any
    edge), its searches on ``workers`` threads of their own; read back from ``stored`` when it was built
    before for the same network and metric (the caller keeps it in memory)."""
    n, count, ed = graph.n_nodes, at.shape[0], graph.edges

    def fits(arrays: stored.Arrays) -> bool:
        return stored.shaped(arrays, {"table": (np.int64, (n, 2 * count))})

    parts = (n, ed.tail, ed.head, ed.tie1, ed.tie2, at, forward.edge, reverse.edge)
    got = stored.kept(
        "landmark-table", parts, lambda: {"table": _table(graph, at, forward, reverse, workers)}, fits
    )
    return np.asarray(got["table"], dtype=np.int64)


def _table(
    graph: RoadGraph, at: NDArray[np.int64], forward: Costs, reverse: Costs, workers: int
) -> NDArray[np.int64]:
    """``landmark_table`` searched."""
    n, count = graph.n_nodes, at.shape[0]
    table = np.full((n, 2 * count), INF, dtype=np.int64)

    def column(j: int) -> None:
        back = j >= count  # column count + i: from landmark i; column i: to it (a reverse search)
        ws = workspace(graph, reverse=not back)
        table[:, j] = _costs_to_or_from(graph, forward if back else reverse, int(at[j % count]), back, ws)

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        list(pool.map(column, range(2 * count)))
    return table


_crossing: weakref.WeakKeyDictionary[RoadGraph, int] = weakref.WeakKeyDictionary()


def crossing_us(graph: RoadGraph) -> int:
    """How long, at least, the network takes to cross: the longest fastest path to or from a landmark (each
    picked farthest from the ones before, so one of them lies near the end of a longest path), in whole
    microseconds. A lower bound on the diameter, the same every time for a network; found once per graph
    (one scan of the whole landmark table) and kept, since every epoch's Step 3 reads it."""
    with _landmarks_lock:
        known = _crossing.get(graph)
    if known is not None:
        return known
    table = landmarks(graph)
    finite = table[table < INF]
    value = int(finite.max()) if finite.size else 0
    with _landmarks_lock:
        _crossing[graph] = value
    return value
