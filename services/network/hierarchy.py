"""A contraction hierarchy of a city's network under the travel time: canonical fastest paths between known
endpoints (the riders' trips, the matched pickups) in a fraction of a search's time.

The hierarchy (Geisberger, Sanders, Schultes and Delling, 2008) orders the nodes and contracts them one by
one; contracting ``v`` adds a shortcut ``u -> w`` for each pair of its remaining neighbours unless a
*witness* path from ``u`` to ``w`` that avoids ``v`` is no worse than ``u -> v -> w``. A query is then two
searches that only climb the order, from the source along arcs to higher nodes and from the target along
arcs from higher nodes; the best meeting node joins the shortest path, whose shortcuts unpack into
original edges.

Every comparison here is the canonical one (``services.network.graph``): labels are ``(cost, tie1, tie2)``
in whole microseconds and tie words, compared in that order, added component by component. That order is
total and adding an edge's label (cost >= 1) strictly raises a label, which is all the hierarchy's
correctness needs: contracting a node keeps the least label between every two remaining nodes (a witness
is taken only when its label is no larger; a witness search that gives up early adds the shortcut, which
is merely redundant), and the query returns the least label over all paths. The least label is the
canonical path's, so the unpacked path is exactly the path ``dijkstra.run`` finds (two different paths
with the same cost and both tie sums equal would need two 47-bit sums to collide at once).

Built once per graph (``hierarchy``; the construction is ``services.network.shortcuts``), in 15-20 seconds
on a metropolitan network, and kept on disk for the next process (``services.network.stored``); queries
share nothing but the read-only hierarchy and run on several threads, each in its own :class:`Lanes`.
"""

from __future__ import annotations

import threading
import weakref
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network import point_to_point, stored, unfolding
from services.network.graph import INF, RoadGraph
from services.network.heaps import _less
from services.network.scratch import Scratch
from services.network.shortcuts import Hierarchy, _pop, _sift_up, build

__all__ = ["Hierarchy", "Lanes", "hierarchy", "stored_or_built", "lanes", "ch_paths", "fastest_paths"]


class Lanes(NamedTuple):
    """One thread's scratch for queries: per direction (row 0 forward, 1 backward) the labels, the arc each
    came along, the heap (nodes, and each node's place in it) and the nodes touched. Nodes, arcs and edges
    are 32-bit, as in the hierarchy's own arrays: the scratch each dispatch thread holds is 92 bytes per
    node rather than 136 (24 MB on a 260,000-node network)."""

    cost: NDArray[np.int64]  # (2, n)
    tie1: NDArray[np.int64]
    tie2: NDArray[np.int64]
    pred: NDArray[np.int32]
    pos: NDArray[np.int32]  # -1 unseen, -2 settled, >= 0 place in the heap
    heap: NDArray[np.int32]
    touched: NDArray[np.int32]
    n_touched: NDArray[np.int64]  # (2,)
    buf: NDArray[np.int32]  # (n,) a path's edges (a least path is simple: fewer edges than nodes)
    stack: NDArray[np.int32]  # (2 n,) the shortcuts being unpacked


def lanes(n_nodes: int) -> Lanes:
    """Fresh query scratch for a network of ``n_nodes`` nodes."""
    return Lanes(
        np.full((2, n_nodes), INF, dtype=np.int64),
        np.zeros((2, n_nodes), dtype=np.int64),
        np.zeros((2, n_nodes), dtype=np.int64),
        np.full((2, n_nodes), -1, dtype=np.int32),
        np.full((2, n_nodes), -1, dtype=np.int32),
        np.zeros((2, n_nodes), dtype=np.int32),
        np.zeros((2, n_nodes), dtype=np.int32),
        np.zeros(2, dtype=np.int64),
        np.zeros(max(n_nodes, 1), dtype=np.int32),
        np.zeros(max(2 * n_nodes, 64), dtype=np.int32),
    )


_built: weakref.WeakKeyDictionary[RoadGraph, Hierarchy | None] = weakref.WeakKeyDictionary()
_built_lock = threading.Lock()


def hierarchy(graph: RoadGraph) -> Hierarchy | None:
    """The hierarchy of ``graph`` under the travel time (None: the network needs too many shortcuts),
    built once per graph and kept with it, and on disk (``stored``) for the next process."""
    with _built_lock:
        if graph not in _built:
            _built[graph] = stored_or_built(graph)
        return _built[graph]


def _spec(n: int) -> dict[str, tuple[type, tuple[int | None, ...]]]:
    """The arrays of a stored ``Hierarchy`` of an ``n``-node network: their dtypes and shapes."""
    wide = ("arc_c", "arc_a", "arc_b", "up_ptr", "dn_ptr")  # int64; every other array is int32
    sizes = {"rank": n, "up_ptr": n + 1, "dn_ptr": n + 1}
    return {f: (np.int64 if f in wide else np.int32, (sizes.get(f),)) for f in Hierarchy._fields}


def stored_or_built(graph: RoadGraph, root: Path | None = None) -> Hierarchy | None:
    """``shortcuts.build``'s hierarchy of ``graph``, read back from ``stored`` (under ``root``, else its
    directory) when it was built before for the same edges, else built and stored. A network that gets no
    hierarchy is stored as no arrays at all."""
    ed = graph.edges
    edges = (graph.n_nodes, ed.tail, ed.head, ed.time_us, ed.tie1, ed.tie2)

    def built() -> stored.Arrays:
        h = build(*edges)
        return {} if h is None else dict(h._asdict())

    def fits(arrays: stored.Arrays) -> bool:
        return not arrays or stored.shaped(arrays, _spec(graph.n_nodes))

    got = stored.kept("hierarchy", edges, built, fits, root)
    return Hierarchy(**got) if got else None  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------------------
# Queries.


@compiled_inline
def _lane_reset(lanes: Lanes) -> None:
    for d in range(2):
        for i in range(lanes.n_touched[d]):
            v = lanes.touched[d, i]
            lanes.cost[d, v] = INF
            lanes.pos[d, v] = -1
            lanes.pred[d, v] = -1
        lanes.n_touched[d] = 0


@compiled_inline
def _lane_seed(lanes: Lanes, d: int, v: int) -> None:
    lanes.cost[d, v] = 0
    lanes.tie1[d, v] = 0
    lanes.tie2[d, v] = 0
    lanes.pred[d, v] = -1
    lanes.heap[d, 0] = v
    lanes.pos[d, v] = 0
    lanes.touched[d, 0] = v
    lanes.n_touched[d] = 1


@compiled_inline
def _stalled(h: Hierarchy, lanes: Lanes, d: int, v: int) -> bool:
    """Stall on demand: ``v``'s label is not final along the climb when a higher node already reached
    reaches it with a smaller label (then nothing climbing from ``v`` can be on a shortest path)."""
    cost, tie1, tie2 = lanes.cost[d], lanes.tie1[d], lanes.tie2[d]
    ptr, arcs = (h.dn_ptr, h.dn) if d == 0 else (h.up_ptr, h.up)
    for i in range(ptr[v], ptr[v + 1]):
        x = arcs[i]
        w = h.arc_tail[x] if d == 0 else h.arc_head[x]
        if cost[w] < INF:
            c = cost[w] + h.arc_c[x]
            if _less(c, tie1[w] + h.arc_a[x], tie2[w] + h.arc_b[x], cost[v], tie1[v], tie2[v]):
                return True
    return False


@compiled
def _meet(h: Hierarchy, lanes: Lanes, s: int, t: int) -> int:
    """The node where the least path from ``s`` to ``t`` reaches its highest rank (-1: none); the two
    climbs' labels and arcs stay in ``lanes``."""
    _lane_reset(lanes)
    _lane_seed(lanes, 0, s)
    _lane_seed(lanes, 1, t)
    size = np.ones(2, dtype=np.int64)
    best_c, best_a, best_b, best = INF, 0, 0, -1
    if s == t:
        return s
    while size[0] > 0 or size[1] > 0:
        d = 0
        if size[0] == 0:
            d = 1
        elif size[1] > 0:
            u0, u1 = lanes.heap[0, 0], lanes.heap[1, 0]
            if _less(
                lanes.cost[1, u1],
                lanes.tie1[1, u1],
                lanes.tie2[1, u1],
                lanes.cost[0, u0],
                lanes.tie1[0, u0],
                lanes.tie2[0, u0],
            ):
                d = 1
        v = lanes.heap[d, 0]
        cv, av, bv = lanes.cost[d, v], lanes.tie1[d, v], lanes.tie2[d, v]
        if not _less(cv, av, bv, best_c, best_a, best_b):
            size[d] = 0  # nothing left in this direction can improve the best
            continue
        size[d] = _pop(lanes.cost[d], lanes.tie1[d], lanes.tie2[d], lanes.pos[d], lanes.heap[d], size[d])
        lanes.pos[d, v] = -2
        o = 1 - d
        if lanes.cost[o, v] < INF:
            c, a, b = cv + lanes.cost[o, v], av + lanes.tie1[o, v], bv + lanes.tie2[o, v]
            if _less(c, a, b, best_c, best_a, best_b):
                best_c, best_a, best_b, best = c, a, b, v
        if _stalled(h, lanes, d, v):
            continue
        ptr, arcs = (h.up_ptr, h.up) if d == 0 else (h.dn_ptr, h.dn)
        for i in range(ptr[v], ptr[v + 1]):
            x = arcs[i]
            w = h.arc_head[x] if d == 0 else h.arc_tail[x]
            if lanes.pos[d, w] == -2:
                continue
            c, a, b = cv + h.arc_c[x], av + h.arc_a[x], bv + h.arc_b[x]
            if _less(c, a, b, lanes.cost[d, w], lanes.tie1[d, w], lanes.tie2[d, w]):
                if lanes.cost[d, w] == INF:
                    lanes.touched[d, lanes.n_touched[d]] = w
                    lanes.n_touched[d] += 1
                lanes.cost[d, w] = c
                lanes.tie1[d, w] = a
                lanes.tie2[d, w] = b
                lanes.pred[d, w] = x
                if lanes.pos[d, w] < 0:
                    lanes.pos[d, w] = size[d]
                    size[d] += 1
                _sift_up(
                    lanes.cost[d],
                    lanes.tie1[d],
                    lanes.tie2[d],
                    lanes.pos[d],
                    lanes.heap[d],
                    lanes.pos[d, w],
                    w,
                )
    return best


@compiled_inline
def _unpack(h: Hierarchy, x: int, stack: NDArray[np.int32], out: NDArray[np.int32], n_out: int) -> int:
    """Append the original edges of arc ``x``, in travel order, to ``out`` from ``n_out``; the new count."""
    top = 1
    stack[0] = x
    while top > 0:
        top -= 1
        y = stack[top]
        if h.arc_edge[y] >= 0:
            out[n_out] = h.arc_edge[y]
            n_out += 1
        else:
            stack[top] = h.arc_hi[y]
            stack[top + 1] = h.arc_lo[y]
            top += 2
    return n_out


@compiled
def _path(h: Hierarchy, lanes: Lanes, s: int, t: int, m: int) -> NDArray[np.int64]:
    """The original edges of the least path from ``s`` to ``t`` through ``m`` (after ``_meet``): the
    climb from ``s`` (its arcs read backwards from ``m``, kept at the end of the stack), then the descent
    to ``t``, each arc unpacked."""
    stack, out = lanes.stack, lanes.buf
    k = 0
    v = m
    top = stack.shape[0]
    while v != s:
        x = lanes.pred[0, v]
        top -= 1
        stack[top] = x
        k += 1
        v = h.arc_tail[x]
    climb = stack[top:].copy()
    n_out = 0
    for i in range(k):
        n_out = _unpack(h, climb[i], stack, out, n_out)
    v = m
    while v != t:
        x = lanes.pred[1, v]
        n_out = _unpack(h, x, stack, out, n_out)
        v = h.arc_head[x]
    return out[:n_out].astype(np.int64)


@compiled
def ch_paths(
    h: Hierarchy, lanes: Lanes, sources: NDArray[np.int64], targets: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The canonical fastest path of every (source, target) pair as CSR ``(ptr, edges)``, as
    ``unfolding.paths``; a pair that cannot be joined gets ``ptr`` -1 at its end and ends the call."""
    n = sources.shape[0]
    ptr = np.zeros(n + 1, dtype=np.int64)
    flat = np.empty(max(64, 32 * n), dtype=np.int64)
    used = 0
    for i in range(n):
        m = _meet(h, lanes, sources[i], targets[i])
        if m < 0:
            ptr[i + 1] = -1
            return ptr, flat[:used]
        flat, used = unfolding.append_path(flat, used, _path(h, lanes, sources[i], targets[i], m))
        ptr[i + 1] = used
    return ptr, flat[:used]


def fastest_paths(
    graph: RoadGraph, scratch: Scratch, sources: NDArray[np.int64], targets: NDArray[np.int64]
) -> list[NDArray[np.int64]]:
    """The canonical fastest path of every (source, target) pair: through the graph's hierarchy, or with
    ``point_to_point.landmark_fastest_paths`` (the same paths) on a network that has none; ``scratch``: the
    thread's scratch.

    Raises
    ------
    ValueError
        When a target cannot be reached from its source.
    """
    h = hierarchy(graph)
    if h is None:
        return point_to_point.landmark_fastest_paths(graph, scratch.forward, sources, targets)
    ln = scratch.extra.get(Lanes)
    if not isinstance(ln, Lanes):
        ln = scratch.extra[Lanes] = lanes(graph.n_nodes)
    src = np.asarray(sources, dtype=np.int64)
    tgt = np.asarray(targets, dtype=np.int64)
    ptr, flat = ch_paths(h, ln, src, tgt)
    return point_to_point.split_paths(ptr, flat, src, tgt)
