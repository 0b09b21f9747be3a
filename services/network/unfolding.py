"""Reading a search's results: interior nodes resolved from the ends of their chain (``resolve``), tree
paths unfolded onto the original edges (``unfold``), labels, the edges of a path, and the compiled batch
searches that return trees and paths (``tree``, ``paths``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network.astar import run_guided
from services.network.dijkstra import run
from services.network.graph import (
    INF,
    Costs,
    Edges,
    SearchGraph,
)
from services.network.heaps import Workspace, _less, _offset_on

__all__ = [
    "resolve",
    "unfold",
    "unfold_many",
    "labels",
    "path_to",
    "walk",
    "tree",
    "paths",
    "append_path",
]


@compiled
def resolve(
    graph: SearchGraph, edges: Edges, costs: Costs, limit: int, v: int, workspace: Workspace
) -> tuple[int, int, int, int, int]:
    """The label of node ``v`` after ``run``: ``(cost, tie1, tie2, super-edge, start offset)``.

    A kept node reads its own label; an interior node takes the best of arriving along each super-edge it
    lies on (from the chain's tail, or from the source when it lies before ``v`` on that chain). Cost is
    ``INF`` when ``v`` is not reached within ``limit`` or cannot be decided because the search stopped
    early. The source itself is ``(0, 0, 0, -1, 0)``.
    """
    source = workspace.info[0]
    if v == source:
        return 0, 0, 0, -1, 0
    kv = graph.kept_of[v]
    if kv >= 0:
        if workspace.state[kv] != -2:
            return INF, 0, 0, -1, 0
        return (
            workspace.cost[kv],
            workspace.tie1[kv],
            workspace.tie2[kv],
            workspace.pse[kv],
            workspace.pstart[kv],
        )
    sk = graph.kept_of[source]
    best_c = INF
    best_a = 0
    best_b = 0
    best_s = -1
    best_start = 0
    for j in range(2):
        s = graph.pos_se[v, j]
        if s < 0:
            continue
        off = graph.pos_off[v, j]
        os = _offset_on(graph.pos_se, graph.pos_off, source, s) if sk < 0 else -1
        if os >= 0 and os < off:
            start = os
            c = 0
            a = 0
            b = 0
        else:
            t = graph.se_tail[s]
            if workspace.state[t] != -2:
                if workspace.info[1] == 0:
                    return INF, 0, 0, -1, 0  # the tail may still be near: undecided
                continue
            start = 0
            c = workspace.cost[t]
            a = workspace.tie1[t]
            b = workspace.tie2[t]
        for p in range(graph.se_ptr[s] + start, graph.se_ptr[s] + off):
            e = graph.se_edges[p]
            c += costs.edge[e]
            a += edges.tie1[e]
            b += edges.tie2[e]
        if _less(c, a, b, best_c, best_a, best_b):
            best_c = c
            best_a = a
            best_b = b
            best_s = s
            best_start = start
    if best_c > limit:
        return INF, 0, 0, -1, 0
    return best_c, best_a, best_b, best_s, best_start


@compiled
def unfold(graph: SearchGraph, edges: Edges, costs: Costs, limit: int, v: int, workspace: Workspace) -> bool:
    """Write ``workspace.pred`` for every original node on the tree path to ``v``; False if ``v`` is not
    reached."""
    c, _a, _b, s, start = resolve(graph, edges, costs, limit, v, workspace)
    if c >= INF:
        return False
    if v == workspace.info[0]:
        return True
    kv = graph.kept_of[v]
    if kv < 0:  # interior: the prefix of its super-edge up to it, then on from the tail
        off = _offset_on(graph.pos_se, graph.pos_off, v, s)
        for p in range(graph.se_ptr[s] + start, graph.se_ptr[s] + off):
            workspace.pred[graph.se_node[p]] = graph.se_edges[p]
        if start != 0:
            return True
        kv = graph.se_tail[s]
    _unfold_from(
        graph.se_ptr,
        graph.se_node,
        graph.se_edges,
        graph.se_tail,
        workspace.pse,
        workspace.pstart,
        workspace.unfolded,
        workspace.pred,
        kv,
    )
    return True


@compiled_inline
def _unfold_from(
    se_ptr: NDArray[np.int64],
    se_node: NDArray[np.int64],
    se_edges: NDArray[np.int64],
    se_tail: NDArray[np.int64],
    pse: NDArray[np.int64],
    pstart: NDArray[np.int64],
    unfolded: NDArray[np.bool_],
    pred: NDArray[np.int64],
    kv: int,
) -> None:
    """``unfold``'s walk from settled kept node ``kv`` toward the source, until a node already unfolded."""
    while not unfolded[kv]:
        unfolded[kv] = True
        s = pse[kv]
        if s < 0:
            break
        start = pstart[kv]
        for p in range(se_ptr[s] + start, se_ptr[s + 1]):
            pred[se_node[p]] = se_edges[p]
        if start != 0:
            break
        kv = se_tail[s]


@compiled
def unfold_many(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    limit: int,
    nodes: NDArray[np.int64],
    workspace: Workspace,
    reached: NDArray[np.bool_],
) -> bool:
    """``unfold`` every one of ``nodes`` (``reached[i]``: node ``i`` was); True when all were.

    One call for many nodes: numba counts a reference for every array of every tuple passed to a compiled
    function, about 0.7-1.7 us per ``resolve`` or ``unfold`` call with the graph, metric and workspace passed
    whole, several times the work of unfolding a node; here a kept node is unfolded from the arrays alone."""
    source = workspace.info[0]
    state = workspace.state
    all_reached = True
    for i in range(nodes.shape[0]):
        v = nodes[i]
        kv = graph.kept_of[v]
        if kv >= 0 and v != source:
            ok = state[kv] == -2
            if ok:
                _unfold_from(
                    graph.se_ptr,
                    graph.se_node,
                    graph.se_edges,
                    graph.se_tail,
                    workspace.pse,
                    workspace.pstart,
                    workspace.unfolded,
                    workspace.pred,
                    kv,
                )
        else:
            ok = unfold(graph, edges, costs, limit, v, workspace)
        reached[i] = ok
        all_reached = all_reached and ok
    return all_reached


@compiled
def labels(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    limit: int,
    nodes: NDArray[np.int64],
    workspace: Workspace,
    out: NDArray[np.int64],
) -> None:
    """``resolve``'s label ``(cost, tie1, tie2)`` of every one of ``nodes`` into ``out[:, i]`` in one call
    (see ``unfold_many``)."""
    source = workspace.info[0]
    for i in range(nodes.shape[0]):
        v = nodes[i]
        kv = graph.kept_of[v]
        if kv >= 0 and v != source:
            if workspace.state[kv] == -2:
                out[0, i] = workspace.cost[kv]
                out[1, i] = workspace.tie1[kv]
                out[2, i] = workspace.tie2[kv]
            else:
                out[0, i] = INF
                out[1, i] = 0
                out[2, i] = 0
        else:
            c, a, b, _s, _start = resolve(graph, edges, costs, limit, v, workspace)
            out[0, i] = c
            out[1, i] = a
            out[2, i] = b


@compiled
def path_to(edges: Edges, towards: int, pred: NDArray[np.int64], source: int, v: int) -> NDArray[np.int64]:
    """Edges of the unfolded tree path between the root ``source`` and ``v``, in travel order: from
    ``source`` to ``v`` in a forward tree (``towards`` 1), from ``v`` to ``source`` in a reverse one."""
    count = 0
    x = v
    while x != source:
        e = pred[x]
        count += 1
        x = edges.tail[e] if towards == 1 else edges.head[e]
    out = np.empty(count, dtype=np.int64)
    x = v
    for i in range(count):
        e = pred[x]
        if towards == 1:
            out[count - 1 - i] = e
            x = edges.tail[e]
        else:
            out[i] = e
            x = edges.head[e]
    return out


@compiled
def walk(edges: Edges, succ: NDArray[np.int64], start: int, root: int) -> NDArray[np.int64]:
    """Edges from ``start`` to ``root`` following a reverse tree's ``succ`` (original edge ids)."""
    return path_to(edges, 0, succ, root, start)


@compiled
def tree(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    queries: NDArray[np.int64],
    workspace: Workspace,
    out_cost: NDArray[np.int64],
) -> None:
    """``run`` then ``unfold`` every query; ``out_cost[i]`` is query ``i``'s cost (``INF`` unreached)."""
    run(graph, edges, costs, source, limit, targets, workspace)
    for i in range(queries.shape[0]):
        if unfold(graph, edges, costs, limit, queries[i], workspace):
            out_cost[i] = resolve(graph, edges, costs, limit, queries[i], workspace)[0]
        else:
            out_cost[i] = INF


@compiled
def paths(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    workspace: Workspace,
    sources: NDArray[np.int64],
    targets: NDArray[np.int64],
    landmarks: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The canonical path of every (source, target) pair in one call, as CSR ``(ptr, edges)``; a pair that
    cannot be joined gets ``ptr`` -1 at its end (``ptr[i + 1] == -1``). With a landmark table ``landmarks``
    (``landmarks``; ``costs`` must be the travel time, or dearer) each search is goal-directed
    (``run_guided``; the same paths); shape (0, 0): plain searches."""
    n = sources.shape[0]
    ptr = np.zeros(n + 1, dtype=np.int64)
    flat = np.empty(max(64, 32 * n), dtype=np.int64)
    used = 0
    tgt = np.empty(1, dtype=np.int64)
    guided = landmarks.shape[0] > 0
    pot = np.empty((3, 0), dtype=np.int64)
    for i in range(n):
        if guided:
            run_guided(graph, edges, costs, sources[i], targets[i], pot, workspace, landmarks)
        else:
            tgt[0] = targets[i]
            run(graph, edges, costs, sources[i], INF, tgt, workspace)
        if not unfold(graph, edges, costs, INF, targets[i], workspace):
            ptr[i + 1] = -1
            return ptr, flat[:used]
        flat, used = append_path(
            flat, used, path_to(edges, graph.towards, workspace.pred, sources[i], targets[i])
        )
        ptr[i + 1] = used
    return ptr, flat[:used]


@compiled_inline
def append_path(
    flat: NDArray[np.int64], used: int, edges: NDArray[np.int64]
) -> tuple[NDArray[np.int64], int]:
    """``edges`` written after the first ``used`` entries of ``flat`` (a bigger copy when it is full): the
    array and its new length (the CSR ``paths`` builds)."""
    if used + edges.shape[0] > flat.shape[0]:
        bigger = np.empty(2 * (used + edges.shape[0]), dtype=np.int64)
        bigger[:used] = flat[:used]
        flat = bigger
    flat[used : used + edges.shape[0]] = edges
    return flat, used + edges.shape[0]
