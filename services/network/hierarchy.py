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

Built once per graph (``hierarchy``), in a few seconds on a metropolitan network; queries share nothing
but the read-only hierarchy and run on several threads, each in its own :class:`Lanes`.
"""

from __future__ import annotations

import threading
import weakref
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network import point_to_point, unfolding
from services.network.graph import INF, RoadGraph
from services.network.scratch import Scratch

__all__ = ["Hierarchy", "Lanes", "hierarchy", "lanes", "ch_paths", "fastest_paths"]

ARCS_PER_EDGE = 3
"""Room for arcs (edges and shortcuts) per edge: a network that needs more (a uniform grid, where
contraction hierarchies are known to degrade) gets no hierarchy, and its paths are searched as before."""

WITNESS_SETTLED = 60
"""Most nodes a witness search settles before it gives up (and the shortcut is added): only the size of
the hierarchy and the time to build it depend on it."""

ESTIMATE_SETTLED = 12
"""The same while only counting the shortcuts a node would need, for the contraction order's keys."""


class Hierarchy(NamedTuple):
    """The contracted network. Arc ``x`` joins ``arc_tail[x] -> arc_head[x]`` with label ``arc_c[x],
    arc_a[x], arc_b[x]``; it is an original edge (``arc_edge[x] >= 0``) or the shortcut of arcs
    ``arc_lo[x]`` then ``arc_hi[x]``. The arcs that climb from ``u`` (to a higher node) are
    ``up[up_ptr[u]:up_ptr[u + 1]]``; the arcs that come down into ``w`` (from a higher node) are
    ``dn[dn_ptr[w]:dn_ptr[w + 1]]``. Indices are 32-bit (a metropolitan hierarchy has millions of arcs)."""

    rank: NDArray[np.int32]
    arc_tail: NDArray[np.int32]
    arc_head: NDArray[np.int32]
    arc_c: NDArray[np.int64]
    arc_a: NDArray[np.int64]
    arc_b: NDArray[np.int64]
    arc_edge: NDArray[np.int32]
    arc_lo: NDArray[np.int32]
    arc_hi: NDArray[np.int32]
    up_ptr: NDArray[np.int64]
    up: NDArray[np.int32]
    dn_ptr: NDArray[np.int64]
    dn: NDArray[np.int32]


class Lanes(NamedTuple):
    """One thread's scratch for queries: per direction (row 0 forward, 1 backward) the labels, the arc each
    came along, the heap (nodes, and each node's place in it) and the nodes touched."""

    cost: NDArray[np.int64]  # (2, n)
    tie1: NDArray[np.int64]
    tie2: NDArray[np.int64]
    pred: NDArray[np.int64]
    pos: NDArray[np.int64]  # -1 unseen, -2 settled, >= 0 place in the heap
    heap: NDArray[np.int64]
    touched: NDArray[np.int64]
    n_touched: NDArray[np.int64]  # (2,)
    buf: NDArray[np.int64]  # (n,) a path's edges (a least path is simple: fewer edges than nodes)
    stack: NDArray[np.int64]  # (2 n,) the shortcuts being unpacked


def lanes(n_nodes: int) -> Lanes:
    """Fresh query scratch for a network of ``n_nodes`` nodes."""
    return Lanes(
        np.full((2, n_nodes), INF, dtype=np.int64),
        np.zeros((2, n_nodes), dtype=np.int64),
        np.zeros((2, n_nodes), dtype=np.int64),
        np.full((2, n_nodes), -1, dtype=np.int64),
        np.full((2, n_nodes), -1, dtype=np.int64),
        np.zeros((2, n_nodes), dtype=np.int64),
        np.zeros((2, n_nodes), dtype=np.int64),
        np.zeros(2, dtype=np.int64),
        np.zeros(max(n_nodes, 1), dtype=np.int64),
        np.zeros(max(2 * n_nodes, 64), dtype=np.int64),
    )


@compiled_inline
def _less(c1: int, a1: int, b1: int, c2: int, a2: int, b2: int) -> bool:
    if c1 != c2:
        return c1 < c2
    if a1 != a2:
        return a1 < a2
    return b1 < b2


# ---------------------------------------------------------------------------------------------------------
# Building: a pool of arcs with linked out- and in-lists per node, witness searches, the node order.


class _Pool(NamedTuple):
    """The arcs while the hierarchy is built, with room for ``ARCS_PER_EDGE`` per edge: ends, label, the
    original edge or the two parts, and the next arc out of the tail and into the head."""

    tail: NDArray[np.int32]
    head: NDArray[np.int32]
    c: NDArray[np.int64]
    a: NDArray[np.int64]
    b: NDArray[np.int64]
    edge: NDArray[np.int32]
    lo: NDArray[np.int32]
    hi: NDArray[np.int32]
    nout: NDArray[np.int32]
    nin: NDArray[np.int32]
    out_first: NDArray[np.int32]
    in_first: NDArray[np.int32]
    size: NDArray[np.int64]  # (1,) arcs used; -1 once the room ran out


@compiled
def _put(p: _Pool, u: int, w: int, c: int, a: int, b: int, edge: int, lo: int, hi: int) -> None:
    """Arc ``u -> w`` with this label, unless one is there already with a label no larger; a larger one is
    overwritten in place (it is no shortcut's part yet: parts are the arcs of a node being contracted).
    With no room left the pool is marked full (``size`` -1)."""
    x = p.out_first[u]
    while x >= 0:
        if p.head[x] == w:
            if _less(c, a, b, p.c[x], p.a[x], p.b[x]):
                p.c[x] = c
                p.a[x] = a
                p.b[x] = b
                p.edge[x] = edge
                p.lo[x] = lo
                p.hi[x] = hi
            return
        x = p.nout[x]
    x = p.size[0]
    if x < 0 or x == p.tail.shape[0]:
        p.size[0] = -1
        return
    p.size[0] = x + 1
    p.tail[x] = u
    p.head[x] = w
    p.c[x] = c
    p.a[x] = a
    p.b[x] = b
    p.edge[x] = edge
    p.lo[x] = lo
    p.hi[x] = hi
    p.nout[x] = p.out_first[u]
    p.out_first[u] = x
    p.nin[x] = p.in_first[w]
    p.in_first[w] = x


class _Witness(NamedTuple):
    """A witness search's scratch: labels, a binary heap of nodes and the nodes touched."""

    c: NDArray[np.int64]
    a: NDArray[np.int64]
    b: NDArray[np.int64]
    pos: NDArray[np.int64]
    heap: NDArray[np.int64]
    touched: NDArray[np.int64]


@compiled_inline
def _sift_up(
    c: NDArray[np.int64],
    a: NDArray[np.int64],
    b: NDArray[np.int64],
    pos: NDArray[np.int64],
    heap: NDArray[np.int64],
    i: int,
    v: int,
) -> None:
    """Put node ``v`` at heap place ``i`` (free, or its own with a label no larger than before) and sift it
    up; nodes are ordered by their labels ``(c, a, b)``."""
    while i > 0:
        parent = (i - 1) >> 1
        w = heap[parent]
        if not _less(c[v], a[v], b[v], c[w], a[w], b[w]):
            break
        heap[i] = w
        pos[w] = i
        i = parent
    heap[i] = v
    pos[v] = i


@compiled_inline
def _pop(
    c: NDArray[np.int64],
    a: NDArray[np.int64],
    b: NDArray[np.int64],
    pos: NDArray[np.int64],
    heap: NDArray[np.int64],
    size: int,
) -> int:
    """Take the heap's root out; returns the new size (the root is ``heap[0]`` before the call)."""
    size -= 1
    if size == 0:
        return 0
    v = heap[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        x = heap[child]
        if child + 1 < size:
            y = heap[child + 1]
            if _less(c[y], a[y], b[y], c[x], a[x], b[x]):
                child += 1
                x = y
        if not _less(c[x], a[x], b[x], c[v], a[v], b[v]):
            break
        heap[i] = x
        pos[x] = i
        i = child
    heap[i] = v
    pos[v] = i
    return size


@compiled
def _witness(
    p: _Pool, done: NDArray[np.bool_], workspace: _Witness, u: int, v: int, limit: int, settle: int
) -> int:
    """Labels of the least paths from ``u`` that avoid ``v`` and the contracted nodes, up to cost ``limit``
    and ``settle`` settled nodes (a label not final when it stops is still the label of a real path: a
    witness taken from it is one). Returns the number of nodes touched (to reset)."""
    n_t = 1
    workspace.touched[0] = u
    workspace.c[u] = 0
    workspace.a[u] = 0
    workspace.b[u] = 0
    workspace.heap[0] = u
    workspace.pos[u] = 0
    size = 1
    settled = 0
    while size > 0 and settled < settle:
        x = workspace.heap[0]
        size = _pop(workspace.c, workspace.a, workspace.b, workspace.pos, workspace.heap, size)
        workspace.pos[x] = -2
        settled += 1
        cx, ax, bx = workspace.c[x], workspace.a[x], workspace.b[x]
        if cx > limit:
            break
        y = p.out_first[x]
        while y >= 0:
            h = p.head[y]
            if h != v and not done[h] and workspace.pos[h] != -2:
                c = cx + p.c[y]
                if c <= limit:
                    a = ax + p.a[y]
                    b = bx + p.b[y]
                    if _less(c, a, b, workspace.c[h], workspace.a[h], workspace.b[h]):
                        if workspace.c[h] == INF:
                            workspace.touched[n_t] = h
                            n_t += 1
                        workspace.c[h] = c
                        workspace.a[h] = a
                        workspace.b[h] = b
                        if workspace.pos[h] < 0:
                            workspace.pos[h] = size
                            size += 1
                        _sift_up(
                            workspace.c,
                            workspace.a,
                            workspace.b,
                            workspace.pos,
                            workspace.heap,
                            workspace.pos[h],
                            h,
                        )
            y = p.nout[y]
    return n_t


@compiled_inline
def _clear(workspace: _Witness, n_t: int) -> None:
    for i in range(n_t):
        x = workspace.touched[i]
        workspace.c[x] = INF
        workspace.pos[x] = -1


@compiled
def _contract(
    p: _Pool, done: NDArray[np.bool_], workspace: _Witness, v: int, add: bool, settle: int
) -> tuple[int, int]:
    """Contract ``v`` (``add``) or only count what it would take: the shortcuts it needs and the arcs it
    removes from the remaining graph."""
    need = 0
    removed = 0
    x = p.out_first[v]
    while x >= 0:
        if not done[p.head[x]]:
            removed += 1
        x = p.nout[x]
    x = p.in_first[v]
    while x >= 0:
        u = p.tail[x]
        if done[u]:
            x = p.nin[x]
            continue
        removed += 1
        limit = 0
        y = p.out_first[v]
        while y >= 0:
            w = p.head[y]
            if w != u and not done[w]:
                limit = max(limit, p.c[x] + p.c[y])
            y = p.nout[y]
        n_t = _witness(p, done, workspace, u, v, limit, settle)
        y = p.out_first[v]
        while y >= 0:
            w = p.head[y]
            if w != u and not done[w]:
                c, a, b = p.c[x] + p.c[y], p.a[x] + p.a[y], p.b[x] + p.b[y]
                if _less(c, a, b, workspace.c[w], workspace.a[w], workspace.b[w]):
                    need += 1
                    if add:
                        _put(p, u, w, c, a, b, -1, x, y)
            y = p.nout[y]
        _clear(workspace, n_t)
        x = p.nin[x]
    return need, removed


@compiled
def _witness_scratch(n: int) -> _Witness:
    return _Witness(
        np.full(n, INF, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.full(n, -1, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
    )


@compiled_inline
def _priority(need: int, removed: int, deleted: int, level: int) -> int:
    """The order's key: twice the edge difference, the neighbours contracted and the level (the
    hierarchy's depth below the node), the usual mix for road networks; only speed depends on it."""
    return 2 * (need - removed) + deleted + level


@compiled
def contraction_order(p: _Pool, n: int) -> NDArray[np.int64]:
    """The nodes in the order they are contracted, least key first, the keys brought up to date lazily:
    a node's key is computed again when it comes first, and it is contracted only if it still is (its
    neighbours' counts of contracted neighbours and levels are kept as they change). Contracts them, the
    shortcuts going to the pool; stops (the order cut short) when the pool is full."""
    done = np.zeros(n, dtype=np.bool_)
    ws = _witness_scratch(n)
    deleted = np.zeros(n, dtype=np.int64)
    level = np.zeros(n, dtype=np.int64)
    # the queue is the labels' heap on (key, node, 0): least key first, ties to the smaller node
    key = np.zeros(n, dtype=np.int64)
    node = np.arange(n, dtype=np.int64)
    zero = np.zeros(n, dtype=np.int64)
    heap = np.zeros(n, dtype=np.int64)
    pos = np.full(n, -1, dtype=np.int64)
    for v in range(n):
        need, removed = _contract(p, done, ws, v, False, ESTIMATE_SETTLED)
        key[v] = _priority(need, removed, 0, 0)
        _sift_up(key, node, zero, pos, heap, v, v)
    size = n
    order = np.zeros(n, dtype=np.int64)
    for r in range(n):
        while True:
            v = heap[0]
            need, removed = _contract(p, done, ws, v, False, ESTIMATE_SETTLED)
            k = _priority(need, removed, deleted[v], level[v])
            if k <= key[v] or size == 1:
                break
            size = _pop(key, node, zero, pos, heap, size)
            key[v] = k
            _sift_up(key, node, zero, pos, heap, size, v)
            size += 1
        size = _pop(key, node, zero, pos, heap, size)
        pos[v] = -2
        _contract(p, done, ws, v, True, WITNESS_SETTLED)
        if p.size[0] < 0:
            return order[:r]
        done[v] = True
        order[r] = v
        _touch_neighbours(p, done, v, deleted, level)
    return order


@compiled
def _touch_neighbours(
    p: _Pool, done: NDArray[np.bool_], v: int, deleted: NDArray[np.int64], level: NDArray[np.int64]
) -> None:
    x = p.out_first[v]
    while x >= 0:
        w = p.head[x]
        if not done[w]:
            deleted[w] += 1
            level[w] = max(level[w], level[v] + 1)
        x = p.nout[x]
    x = p.in_first[v]
    while x >= 0:
        w = p.tail[x]
        if not done[w]:
            deleted[w] += 1
            level[w] = max(level[w], level[v] + 1)
        x = p.nin[x]


def _csr(
    owner: NDArray[np.int32], which: NDArray[np.int64], n: int
) -> tuple[NDArray[np.int64], NDArray[np.int32]]:
    """The arcs ``which``, grouped by their ``owner`` node: (pointers, arcs)."""
    order = np.argsort(owner[which], kind="stable")
    ptr = np.zeros(n + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(np.bincount(owner[which], minlength=n))
    return ptr, which[order].astype(np.int32)


def build(
    n: int,
    tail: NDArray[np.int64],
    head: NDArray[np.int64],
    cost: NDArray[np.int64],
    tie1: NDArray[np.int64],
    tie2: NDArray[np.int64],
) -> Hierarchy | None:
    """The hierarchy of the graph of ``n`` nodes and edges ``tail -> head`` with labels ``(cost, tie1,
    tie2)`` (cost >= 1); of parallel edges the one with the least label is kept, self-loops are dropped.
    None when it would take more than ``ARCS_PER_EDGE`` arcs per edge."""
    cap = max(64, ARCS_PER_EDGE * int(tail.shape[0]))

    def room(dtype: type) -> NDArray[Any]:
        return np.zeros(cap, dtype=dtype)

    p = _Pool(
        room(np.int32),
        room(np.int32),
        room(np.int64),
        room(np.int64),
        room(np.int64),
        room(np.int32),
        room(np.int32),
        room(np.int32),
        room(np.int32),
        room(np.int32),
        np.full(n, -1, dtype=np.int32),
        np.full(n, -1, dtype=np.int32),
        np.zeros(1, dtype=np.int64),
    )
    _load(p, tail.astype(np.int64), head.astype(np.int64), cost, tie1, tie2)
    order = contraction_order(p, n)
    if order.shape[0] < n:
        return None
    rank = np.empty(n, dtype=np.int32)
    rank[order] = np.arange(n, dtype=np.int32)
    k = int(p.size[0])
    arc_tail, arc_head = p.tail[:k].copy(), p.head[:k].copy()
    climbs = rank[arc_tail] < rank[arc_head]
    up_ptr, up = _csr(arc_tail, np.flatnonzero(climbs), n)
    dn_ptr, dn = _csr(arc_head, np.flatnonzero(~climbs), n)
    return Hierarchy(
        rank=rank,
        arc_tail=arc_tail,
        arc_head=arc_head,
        arc_c=p.c[:k].copy(),
        arc_a=p.a[:k].copy(),
        arc_b=p.b[:k].copy(),
        arc_edge=p.edge[:k].copy(),
        arc_lo=p.lo[:k].copy(),
        arc_hi=p.hi[:k].copy(),
        up_ptr=up_ptr,
        up=up,
        dn_ptr=dn_ptr,
        dn=dn,
    )


@compiled
def _load(
    p: _Pool,
    tail: NDArray[np.int64],
    head: NDArray[np.int64],
    cost: NDArray[np.int64],
    tie1: NDArray[np.int64],
    tie2: NDArray[np.int64],
) -> None:
    for e in range(tail.shape[0]):
        if tail[e] != head[e]:
            _put(p, tail[e], head[e], cost[e], tie1[e], tie2[e], e, -1, -1)


_built: weakref.WeakKeyDictionary[RoadGraph, Hierarchy | None] = weakref.WeakKeyDictionary()
_built_lock = threading.Lock()


def hierarchy(graph: RoadGraph) -> Hierarchy | None:
    """The hierarchy of ``graph`` under the travel time (None: the network needs too many shortcuts),
    built once per graph and kept with it."""
    with _built_lock:
        if graph not in _built:
            ed = graph.edges
            _built[graph] = build(graph.n_nodes, ed.tail, ed.head, ed.time_us, ed.tie1, ed.tie2)
        return _built[graph]


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
def _unpack(h: Hierarchy, x: int, stack: NDArray[np.int64], out: NDArray[np.int64], n_out: int) -> int:
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
    return out[:n_out].copy()


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
