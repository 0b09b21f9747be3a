"""Canonical shortest paths on a contracted search graph (compiled kernels and their wrappers).

One Dijkstra serves every search of an epoch: the fastest-path trees of riders and POIs, the pickup
searches bounded by the matching radius, the utility-discounted trees of Algorithm 1 and the legs of
matched pairs. Costs are positive whole microseconds and ties are broken by the per-edge tie words
(``services.network.graph``): a node's label is ``(cost, tie1, tie2)``, compared in that order, and the
heap is keyed on ``cost`` alone. That is enough for an exact lexicographic search: every edge costs at least
1, so all labels that could still improve a node of cost ``c`` come from nodes of smaller cost, which are
settled (and have relaxed their edges) before any node of cost ``c`` is taken from the heap.

The search settles *kept* nodes only (``services.network.contraction``); a chain's interior node is resolved
from the ends of its chain when asked for (``resolve``), and the predecessor edges of the original nodes on
the tree path to a node are written when it is unfolded (``unfold``). Results are those of a plain
Dijkstra with the same rule on the original network (``tests/unit/test_search.py`` checks this against a
reference written in Python).

A search's state lives in a :class:`Workspace` of the caller's (one per thread); ``pred`` holds original
edge ids: the edge entering a node on its path from the source in a forward search, the edge leaving it
toward the root in a reverse one.
"""

from __future__ import annotations

import threading
import weakref
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network.graph import (
    INF,
    Costs,
    Edges,
    Lazy,
    RoadGraph,
    SearchGraph,
    kappa_cost,
    lazy_fill,
    no_lazy,
)

__all__ = [
    "RING",
    "Workspace",
    "workspace",
    "run",
    "grow",
    "run_guided",
    "guided",
    "Guide",
    "tree_guide",
    "CLEAN_WORDS",
    "path_cells",
    "landmarks",
    "crossing_us",
    "resolve",
    "unfold",
    "unfold_many",
    "labels",
    "path_to",
    "tree",
    "fastest_path",
    "fastest_paths",
    "paths",
    "append_path",
    "split_paths",
    "path",
    "walk",
]


RING = 1 << 18
"""Most buckets a workspace's bucket queue has; a metric whose ``span`` is larger than the workspace's ring
is searched with the heap."""


class Workspace(NamedTuple):
    """Scratch arrays of one search (sizes: K kept nodes, n original nodes)."""

    cost: NDArray[np.int64]  # (K,) label of each kept node
    tie1: NDArray[np.int64]
    tie2: NDArray[np.int64]
    pse: NDArray[np.int64]  # super-edge the label came along, -1 at the source
    pstart: NDArray[np.int64]  # offset on pse where it started (> 0: an interior source)
    state: NDArray[np.int64]  # -1 unseen, -2 settled, -3 dead end reached, >= 0 queued (heap: position)
    nxt: NDArray[np.int64]  # (K,) bucket lists (doubly linked) / heap keys
    prv: NDArray[np.int64]  # (K,) bucket lists / heap nodes
    ring: NDArray[np.int64]  # (RING,) first node of each bucket, -1 empty
    bits: NDArray[np.int64]  # (RING / 64,) non-empty buckets
    need: NDArray[np.bool_]
    unfolded: NDArray[np.bool_]  # (K,)
    touched: NDArray[np.int64]  # (K,) kept nodes whose entries the next search resets
    pred: NDArray[np.int64]  # (n,) original edge ids, valid on unfolded tree paths only
    info: NDArray[np.int64]  # [source, complete (1) or stopped early (0), number of touched nodes]
    hkey: NDArray[np.int64]  # (K, 3) run_guided's heap: the key of each entry, beside it


def workspace(graph: RoadGraph, reverse: bool = False) -> Workspace:
    """Fresh scratch arrays for searches on ``graph.forward`` (or ``graph.reverse``). The ring holds the
    travel time's span 16 times over (the discounted metrics of Algorithm 1 divide the cheapest super-edge
    by at most 1 / (1 - kappa)), at most ``RING`` buckets."""
    g = graph.reverse if reverse else graph.forward
    k = int(g.kept.shape[0])
    time_span = (graph.time_reverse if reverse else graph.time_forward).span
    ring = min(RING, 64 * ((16 * time_span + 63) // 64))
    return Workspace(
        cost=np.full(k, INF, dtype=np.int64),
        tie1=np.zeros(k, dtype=np.int64),
        tie2=np.zeros(k, dtype=np.int64),
        pse=np.full(k, -1, dtype=np.int64),
        pstart=np.zeros(k, dtype=np.int64),
        state=np.full(k, -1, dtype=np.int64),
        nxt=np.zeros(k, dtype=np.int64),
        prv=np.zeros(k, dtype=np.int64),
        ring=np.full(ring, -1, dtype=np.int64),
        bits=np.zeros(ring // 64, dtype=np.int64),
        need=np.zeros(k, dtype=np.bool_),
        unfolded=np.zeros(k, dtype=np.bool_),
        touched=np.zeros(k, dtype=np.int64),
        pred=np.full(graph.n_nodes, -1, dtype=np.int64),
        info=np.zeros(3, dtype=np.int64),
        hkey=np.zeros((k, 3), dtype=np.int64),
    )


@compiled_inline
def _less(c1: int, a1: int, b1: int, c2: int, a2: int, b2: int) -> bool:
    """Label (c1, a1, b1) before (c2, a2, b2)."""
    if c1 != c2:
        return c1 < c2
    if a1 != a2:
        return a1 < a2
    return b1 < b2


@compiled_inline
def _sift_up(
    keys: NDArray[np.int64], nodes: NDArray[np.int64], state: NDArray[np.int64], i: int, key: int, k: int
) -> None:
    while i > 0:
        parent = (i - 1) >> 2
        pk = keys[parent]
        if pk <= key:
            break
        keys[i] = pk
        w = nodes[parent]
        nodes[i] = w
        state[w] = i
        i = parent
    keys[i] = key
    nodes[i] = k
    state[k] = i


@compiled_inline
def _pop(keys: NDArray[np.int64], nodes: NDArray[np.int64], state: NDArray[np.int64], size: int) -> int:
    """Remove the root of the 4-ary heap (its node is ``nodes[0]`` before the call); new size."""
    size -= 1
    if size == 0:
        return 0
    key = keys[size]
    k = nodes[size]
    i = 0
    while True:
        first = 4 * i + 1
        if first >= size:
            break
        child = first
        ck = keys[first]
        last = min(first + 4, size)
        for c in range(first + 1, last):
            if keys[c] < ck:
                ck = keys[c]
                child = c
        if key <= ck:
            break
        keys[i] = ck
        w = nodes[child]
        nodes[i] = w
        state[w] = i
        i = child
    keys[i] = key
    nodes[i] = k
    state[k] = i
    return size


@compiled_inline
def _link(
    ring: NDArray[np.int64],
    bits: NDArray[np.int64],
    nxt: NDArray[np.int64],
    prv: NDArray[np.int64],
    b: int,
    h: int,
) -> None:
    """Put kept node ``h`` first in bucket ``b``."""
    first = ring[b]
    nxt[h] = first
    prv[h] = -1
    if first >= 0:
        prv[first] = h
    else:
        bits[b >> 6] |= np.int64(1) << (b & 63)
    ring[b] = h


@compiled_inline
def _unlink(
    ring: NDArray[np.int64],
    bits: NDArray[np.int64],
    nxt: NDArray[np.int64],
    prv: NDArray[np.int64],
    b: int,
    h: int,
) -> None:
    """Take kept node ``h`` out of bucket ``b``."""
    a = prv[h]
    z = nxt[h]
    if a >= 0:
        nxt[a] = z
    else:
        ring[b] = z
        if z < 0:
            bits[b >> 6] &= ~(np.int64(1) << (b & 63))
    if z >= 0:
        prv[z] = a


@compiled_inline
def _next_bucket(bits: NDArray[np.int64], span: int, p: int) -> int:
    """The first non-empty bucket at or after ``p``, cyclically (one must exist)."""
    n_words = (span + 63) >> 6
    i = p >> 6
    word = bits[i] & (np.int64(-1) << (p & 63))
    while word == 0:
        i += 1
        if i == n_words:
            i = 0
        word = bits[i]
    low = word & -word
    idx = 0
    if (low >> 32) != 0:
        idx += 32
        low >>= 32
    if (low >> 16) != 0:
        idx += 16
        low >>= 16
    if (low >> 8) != 0:
        idx += 8
        low >>= 8
    if (low >> 4) != 0:
        idx += 4
        low >>= 4
    if (low >> 2) != 0:
        idx += 2
        low >>= 2
    if (low >> 1) != 0:
        idx += 1
    return i * 64 + idx


@compiled_inline
def _offset_on(pos_se: NDArray[np.int64], pos_off: NDArray[np.int64], v: int, s: int) -> int:
    """Offset of interior node ``v`` on super-edge ``s`` (-1 when it does not lie on it)."""
    for j in range(2):
        if pos_se[v, j] == s:
            return int(pos_off[v, j])
    return -1


@compiled_inline
def _reset(ws: Workspace) -> None:
    """Forget what the last search touched (the ring is left empty by every search)."""
    for i in range(ws.info[2]):
        k = ws.touched[i]
        ws.cost[k] = INF
        ws.state[k] = -1
        ws.need[k] = False
        ws.unfolded[k] = False


@compiled_inline
def _need_targets(g: SearchGraph, source: int, targets: NDArray[np.int64], ws: Workspace) -> tuple[int, int]:
    """Mark the kept nodes a search must settle before every target can be resolved: a kept target itself,
    for an interior target the tails of its super-edges (unless the source lies before it on one). Returns
    the number of nodes touched so far and of nodes to settle."""
    sk = g.kept_of[source]
    n_touched = 0
    remaining = 0
    for t in targets:
        if t == source:
            continue
        kt = g.kept_of[t]
        if kt >= 0:
            if not ws.need[kt]:
                ws.need[kt] = True
                ws.touched[n_touched] = kt
                n_touched += 1
                remaining += 1
            continue
        for j in range(2):
            s = g.pos_se[t, j]
            if s < 0:
                continue
            if sk < 0:
                os = _offset_on(g.pos_se, g.pos_off, source, s)
                if os >= 0 and os < g.pos_off[t, j]:
                    continue  # reached from the source along this very super-edge
            kt = g.se_tail[s]
            if not ws.need[kt]:
                ws.need[kt] = True
                ws.touched[n_touched] = kt
                n_touched += 1
                remaining += 1
    return n_touched, remaining


@compiled_inline
def _seed(
    g: SearchGraph, ed: Edges, edge_cost: NDArray[np.int64], source: int, sk: int, j: int
) -> tuple[int, int, int, int, int, int]:
    """The ``j``-th first label of a search from ``source``: ``(kept node, cost, tie1, tie2, super-edge,
    start offset)``; the source itself when it is kept (j = 0), else the head of the ``j``-th super-edge it
    lies on with the cost of the rest of that super-edge (kept node -1: no such super-edge)."""
    if sk >= 0:
        return sk, 0, 0, 0, -1, 0
    s = g.pos_se[source, j]
    if s < 0:
        return -1, 0, 0, 0, -1, 0
    os = g.pos_off[source, j]
    c = 0
    a = 0
    b = 0
    for p in range(g.se_ptr[s] + os, g.se_ptr[s + 1]):
        e = g.se_edges[p]
        c += edge_cost[e]
        a += ed.tie1[e]
        b += ed.tie2[e]
    return g.se_head[s], c, a, b, s, os


@compiled_inline
def _lazy_ends(
    g: SearchGraph, ed: Edges, costs: Costs, lazy: Lazy, source: int, targets: NDArray[np.int64]
) -> None:
    """Cost, edge by edge, the super-edges a search's paths may start or end inside: the source's and the
    interior targets' chains (``search.resolve`` reads their edges' costs)."""
    for j in range(2):
        if g.kept_of[source] < 0 and g.pos_se[source, j] >= 0:
            lazy_fill(g, ed, costs, lazy, g.pos_se[source, j])
        for t in targets:
            if g.kept_of[t] < 0 and g.pos_se[t, j] >= 0:
                lazy_fill(g, ed, costs, lazy, g.pos_se[t, j])


@compiled_inline
def _crossing_cost(
    se_ptr: NDArray[np.int64],
    se_edges: NDArray[np.int64],
    ec_ptr: NDArray[np.int64],
    ec_cell: NDArray[np.int64],
    time_s: NDArray[np.float64],
    zmask: NDArray[np.bool_],
    term: NDArray[np.float64],
    umax: float,
    kappa: float,
    s: int,
) -> int:
    """A lazy metric's cost of super-edge ``s``, one of whose edges enters a cell (``graph.lazy_edge``
    summed over its edges); the searches pass it plain arrays, since a call that takes records counts a
    reference to each of their arrays."""
    c = 0
    for p in range(se_ptr[s], se_ptr[s + 1]):
        e = se_edges[p]
        u = 0.0
        for j in range(ec_ptr[e] + 1, ec_ptr[e + 1]):
            if not zmask[ec_cell[j]]:
                u += term[ec_cell[j]]
        c += kappa_cost(time_s[e], u, umax, kappa)
    return c


@compiled
def run(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    ws: Workspace,
) -> None:
    """``grow`` with the metric held in ``costs``."""
    grow(g, ed, costs, source, limit, targets, ws, no_lazy())


@compiled_inline
def _grow_seed(
    g: SearchGraph, ed: Edges, costs: Costs, ws: Workspace, source: int, limit: int, n_touched: int
) -> tuple[int, int]:
    """Queue the first labels of a search from ``source`` within ``limit`` (in the ring, or the heap when
    the metric is too spread for it); returns the queue's size and the touched nodes' count."""
    cost, tie1, tie2, state = ws.cost, ws.tie1, ws.tie2, ws.state
    ring, bits, nxt, prv = ws.ring, ws.bits, ws.nxt, ws.prv
    width, span = costs.width, costs.span
    use_ring = span <= ring.shape[0]
    sk = g.kept_of[source]
    size = 0
    for j in range(1 if sk >= 0 else 2):
        h, c, a, b, s, os = _seed(g, ed, costs.edge, source, sk, j)
        if h < 0 or c > limit:
            continue
        if not _less(c, a, b, cost[h], tie1[h], tie2[h]):
            continue
        if cost[h] == INF and not ws.need[h]:
            ws.touched[n_touched] = h
            n_touched += 1
        old = cost[h]
        cost[h] = c
        tie1[h] = a
        tie2[h] = b
        ws.pse[h] = s
        ws.pstart[h] = os
        if use_ring:
            if state[h] >= 0:
                _unlink(ring, bits, nxt, prv, (old // width) % span, h)
                size -= 1
            _link(ring, bits, nxt, prv, (c // width) % span, h)
            state[h] = 0
            size += 1
        elif state[h] >= 0:
            _sift_up(nxt, prv, state, state[h], c, h)
        else:
            _sift_up(nxt, prv, state, size, c, h)
            size += 1
    return size, n_touched


@compiled_inline
def _grow_leave(ws: Workspace, costs: Costs, n_touched: int, complete: int) -> None:
    """Leave the workspace as the next search expects it: a node reached from one that stopped the search
    is not known to be final; the ring is left empty. Records whether the search was ``complete`` and the
    number of nodes it touched."""
    use_ring = costs.span <= ws.ring.shape[0]
    for i in range(n_touched):
        k = ws.touched[i]
        if ws.state[k] == -3:  # reached from a node that stopped the search: not known to be final
            ws.state[k] = -1
        elif ws.state[k] >= 0 and use_ring:  # still queued: leave the ring empty for the next search
            b = (ws.cost[k] // costs.width) % costs.span
            ws.ring[b] = -1
            ws.bits[b >> 6] = 0
    ws.info[1] = complete
    ws.info[2] = n_touched


@compiled_inline
def _rebucket(
    ring: NDArray[np.int64],
    bits: NDArray[np.int64],
    nxt: NDArray[np.int64],
    prv: NDArray[np.int64],
    b: int,
    to: int,
    h: int,
) -> None:
    """Move kept node ``h`` from bucket ``b`` to bucket ``to``."""
    if b != to:
        _unlink(ring, bits, nxt, prv, b, h)
        _link(ring, bits, nxt, prv, to, h)


@compiled_inline
def _label(
    cost: NDArray[np.int64],
    tie1: NDArray[np.int64],
    tie2: NDArray[np.int64],
    pse: NDArray[np.int64],
    pstart: NDArray[np.int64],
    h: int,
    c: int,
    a: int,
    b: int,
    s: int,
) -> None:
    """Give kept node ``h`` the label ``(c, a, b)``, reached along the whole of super-edge ``s``."""
    cost[h] = c
    tie1[h] = a
    tie2[h] = b
    pse[h] = s
    pstart[h] = 0


@compiled_inline
def _settle_dead_ends(
    indptr: NDArray[np.int64],
    se_head: NDArray[np.int64],
    state: NDArray[np.int64],
    need: NDArray[np.bool_],
    k: int,
    remaining: int,
    early: bool,
) -> tuple[int, bool]:
    """Settle the dead ends reached from kept node ``k`` once its super-edges are relaxed: ``k`` is their
    only way in, so their labels are final. Returns the number of nodes the search must still settle, and
    whether it may stop (``early``: it has targets, and every one can now be resolved)."""
    stop = False
    for s in range(indptr[k], indptr[k + 1]):
        h = se_head[s]
        if state[h] == -3:
            state[h] = -2
            if need[h]:
                remaining -= 1
                if remaining == 0 and early:
                    stop = True
    return remaining, stop


# Every search of an epoch runs grow's loop. Its arrays are taken from the records once per search, at the
# top, and the loop's helpers take plain arrays: numba counts a reference for every array it takes from a
# record, so a helper taking the records would take them again for every settled node. Even with plain
# arrays, a helper that spans both the ring's and the heap's branch (taking the next node, queueing one), or
# that writes an array after an inlined call, leaves reference counting in the loop (measured: up to 1.75
# times the time); the loop keeps those steps in its own body, and its helpers time within 2 % of the loop
# written out (Chengdu and the generated metropolis, plain and lazy metrics).
@compiled
def grow(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    ws: Workspace,
    lazy: Lazy,
) -> None:
    """Grow the canonical shortest-path tree from ``source`` (all kept nodes with cost <= ``limit``).

    With ``targets`` non-empty the search stops as soon as every target can be resolved: a kept target is
    settled, and for an interior target both ends of its chain are (unless the source lies before it on
    that chain). ``ws`` is reset here; read the result with ``resolve`` and ``unfold``.

    Nodes are taken from a bucket queue of width ``costs.width`` (the cheapest super-edge): every label in
    the lowest non-empty bucket is final, because anything that could still improve it would come along a
    super-edge from a node of the same bucket and so cost at least one width more. Within a bucket the
    order does not matter. Metrics too spread for the ring use a 4-ary heap on the cost instead.

    With ``lazy.on`` the metric is computed as the search goes (``graph.Lazy``): each super-edge when it is
    relaxed, the source's and the targets' chains edge by edge before the search starts; ``costs.width``
    and ``costs.span`` must then bound every super-edge's cost from below and above.
    """
    cost, tie1, tie2, pse, pstart, state = ws.cost, ws.tie1, ws.tie2, ws.pse, ws.pstart, ws.state
    nxt, prv, ring, bits, need, touched = ws.nxt, ws.prv, ws.ring, ws.bits, ws.need, ws.touched
    indptr, se_head, se_tie1, se_tie2, dead_end = g.indptr, g.se_head, g.se_tie1, g.se_tie2, g.dead_end
    lazy_on, fixed, zmask, term = lazy.on, lazy.fixed, lazy.zmask, lazy.term
    se_ptr, se_edges, ec_ptr, ec_cell, time_s = g.se_ptr, g.se_edges, ed.ec_ptr, ed.ec_cell, ed.time_s
    umax, kappa, width, span, se_cost = lazy.umax, lazy.kappa, costs.width, costs.span, costs.se
    use_ring = span <= ring.shape[0]
    _reset(ws)
    ws.info[0] = source
    n_touched, remaining = _need_targets(g, source, targets, ws)
    early = targets.shape[0] > 0
    size, pos = 0, 0  # queued nodes; ring: the bucket being emptied
    if lazy_on:
        _lazy_ends(g, ed, costs, lazy, source, targets)
    if not (early and remaining == 0):
        size, n_touched = _grow_seed(g, ed, costs, ws, source, limit, n_touched)
        if use_ring and size > 0:
            pos = _next_bucket(bits, span, 0)
    complete = 1
    while size > 0:
        if use_ring:
            k = ring[pos]
            if k < 0:
                pos = _next_bucket(bits, span, pos)
                k = ring[pos]
            _unlink(ring, bits, nxt, prv, pos, k)
            size -= 1
            d = cost[k]
        else:
            k = prv[0]
            d = nxt[0]
            size = _pop(nxt, prv, state, size)
        state[k] = -2
        if need[k]:
            remaining -= 1
            if remaining == 0 and early:
                complete = 0
                break
        a0, b0 = tie1[k], tie2[k]
        for s in range(indptr[k], indptr[k + 1]):
            h = se_head[s]
            st = state[h]
            if st == -2:
                continue
            if not lazy_on:
                c = d + se_cost[s]
            elif fixed[s] >= 0:
                c = d + fixed[s]
            else:
                c = d + _crossing_cost(se_ptr, se_edges, ec_ptr, ec_cell, time_s, zmask, term, umax, kappa, s)
            if c > limit:
                continue
            a, b = a0 + se_tie1[s], b0 + se_tie2[s]
            ch = cost[h]
            if c < ch or (c == ch and (a < tie1[h] or (a == tie1[h] and b < tie2[h]))):
                _label(cost, tie1, tie2, pse, pstart, h, c, a, b, s)
                if st == -1:
                    if ch == INF and not need[h]:
                        touched[n_touched] = h
                        n_touched += 1
                    if dead_end[h]:
                        state[h] = -3  # its only way in is from k: settled once k's edges are done
                    elif use_ring:
                        _link(ring, bits, nxt, prv, (c // width) % span, h)
                        state[h] = 0
                        size += 1
                    else:
                        _sift_up(nxt, prv, state, size, c, h)
                        size += 1
                elif st >= 0 and c < ch:
                    if use_ring:
                        _rebucket(ring, bits, nxt, prv, (ch // width) % span, (c // width) % span, h)
                    else:
                        _sift_up(nxt, prv, state, st, c, h)
        remaining, stop = _settle_dead_ends(indptr, se_head, state, need, k, remaining, early)
        if stop:
            complete = 0
            break
    _grow_leave(ws, costs, n_touched, complete)


@compiled_inline
def _put(
    heap: NDArray[np.int64],
    hkey: NDArray[np.int64],
    state: NDArray[np.int64],
    i: int,
    k: int,
    c: int,
    a: int,
    b: int,
) -> None:
    """Heap entry ``i`` := node ``k`` with key ``(c, a, b)``."""
    heap[i] = k
    hkey[i, 0] = c
    hkey[i, 1] = a
    hkey[i, 2] = b
    state[k] = i


@compiled_inline
def _guided_up(
    heap: NDArray[np.int64],
    hkey: NDArray[np.int64],
    state: NDArray[np.int64],
    i: int,
    k: int,
    c: int,
    a: int,
    b: int,
) -> None:
    """Put node ``k`` with key ``(c, a, b)`` at heap position ``i`` (a free slot, or ``k``'s own with a key
    no larger than before) and sift it up. Keys sit beside the entries: a comparison reads one row."""
    while i > 0:
        p = (i - 1) >> 1
        if not _less(c, a, b, hkey[p, 0], hkey[p, 1], hkey[p, 2]):
            break
        _put(heap, hkey, state, i, heap[p], hkey[p, 0], hkey[p, 1], hkey[p, 2])
        i = p
    _put(heap, hkey, state, i, k, c, a, b)


@compiled_inline
def _guided_pop(heap: NDArray[np.int64], hkey: NDArray[np.int64], state: NDArray[np.int64], size: int) -> int:
    """Remove the root of the binary heap (``heap[0]`` before the call); new size."""
    size -= 1
    if size == 0:
        return 0
    k, c0, c1, c2 = heap[size], hkey[size, 0], hkey[size, 1], hkey[size, 2]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        if c + 1 < size and _less(
            hkey[c + 1, 0], hkey[c + 1, 1], hkey[c + 1, 2], hkey[c, 0], hkey[c, 1], hkey[c, 2]
        ):
            c += 1
        if not _less(hkey[c, 0], hkey[c, 1], hkey[c, 2], c0, c1, c2):
            break
        _put(heap, hkey, state, i, heap[c], hkey[c, 0], hkey[c, 1], hkey[c, 2])
        i = c
    _put(heap, hkey, state, i, k, c0, c1, c2)
    return size


@compiled_inline
def _bound(lm: NDArray[np.int64], tl: NDArray[np.int64], v: int) -> int:
    """The landmarks' lower bound on the travel time from node ``v`` to the target whose row is ``tl``
    (``landmarks``): ``d(v, L) - d(t, L)`` and ``d(L, t) - d(L, v)`` by the triangle inequality, the largest
    over the landmarks (at least 0); ``INF`` when ``v`` cannot reach a landmark the target reaches, so
    cannot reach the target. Each term grows along an edge by at most the edge's time, so the largest
    does too: a potential for ``run_guided``."""
    n = tl.shape[0] // 2
    best = 0
    for i in range(n):
        to_t = tl[i]
        if to_t < INF:
            to_v = lm[v, i]
            if to_v >= INF:
                return INF
            if to_v - to_t > best:
                best = to_v - to_t
        from_t = tl[n + i]
        from_v = lm[v, n + i]
        if from_t < INF and from_v < INF and from_t - from_v > best:
            best = from_t - from_v
    return best


class Guide(NamedTuple):
    """Where ``guided`` reads its potential (the first that is given): a landmark table ``lm`` (n, 2L)
    (``landmarks``; the travel-time bound, ties 0); an in-tree's labels, the arrays of the reverse
    workspace it was grown in (``tree_*``, (K,) each: kept indices are the same both ways), grown to
    ``cutoff - 1`` and not stopped early, so that a node it did not settle costs at least ``cutoff``; or
    ``pot`` (3, K), a label per kept node.

    With an in-tree, ``clean`` (K, ``CLEAN_WORDS``) may hold the cells each settled node's in-tree path
    enters (``path_cells``) and ``zbits`` the cells whose entering edges the searched metric prices
    differently from the in-tree's (as ``cell_bit`` sets; ``clean`` of shape (0, W): no such test)."""

    pot: NDArray[np.int64]
    lm: NDArray[np.int64]
    tree_cost: NDArray[np.int64]
    tree_tie1: NDArray[np.int64]
    tree_tie2: NDArray[np.int64]
    tree_state: NDArray[np.int64]
    cutoff: int
    clean: NDArray[np.uint64]
    zbits: NDArray[np.uint64]


CLEAN_WORDS = 4
"""Words of a cell set (``cell_bit``): cell ``c`` is bit ``c % (64 * CLEAN_WORDS)``, so on a network of more
cells two cells may share a bit (a set then holds more cells than it should, never fewer)."""


@compiled_inline
def cell_bit(bits: NDArray[np.uint64], c: int) -> None:
    """Add cell ``c`` to the cell set ``bits`` (``CLEAN_WORDS`` words)."""
    b = c % (64 * CLEAN_WORDS)
    bits[b >> 6] |= np.uint64(1) << np.uint64(b & 63)


@compiled
def path_cells(
    g: SearchGraph,
    ed: Edges,
    tree: Workspace,
    out: NDArray[np.uint64],
    done: NDArray[np.int64],
    stamp: int,
    stack: NDArray[np.int64],
) -> None:
    """For every kept node the in-tree grown in ``tree`` (``run`` on the reverse graph ``g``) settled, the
    cells its tree path to the root enters (each edge's cells but its first) into ``out[k]`` as a
    ``cell_bit`` set; ``done[k] = stamp`` marks each node written. ``stack``: scratch of K entries."""
    for i in range(tree.info[2]):
        k0 = tree.touched[i]
        if tree.state[k0] != -2 or done[k0] == stamp:
            continue
        top = 0
        k = k0
        while True:  # toward the root, to a node written or the root's super-edge
            stack[top] = k
            top += 1
            s = tree.pse[k]
            if s < 0 or tree.pstart[k] != 0:
                break
            k = g.se_tail[s]
            if done[k] == stamp:
                break
        while top > 0:  # back, each node's set from the next node's toward the root
            top -= 1
            k = stack[top]
            s = tree.pse[k]
            for w in range(CLEAN_WORDS):
                out[k, w] = 0
            if s >= 0:
                start = tree.pstart[k]
                if start == 0:
                    nxt = g.se_tail[s]
                    for w in range(CLEAN_WORDS):
                        out[k, w] = out[nxt, w]
                for p in range(g.se_ptr[s] + start, g.se_ptr[s + 1]):
                    e = g.se_edges[p]
                    for j in range(ed.ec_ptr[e] + 1, ed.ec_ptr[e + 1]):
                        cell_bit(out[k], ed.ec_cell[j])
            done[k] = stamp


@compiled
def tree_guide(tree: Workspace, limit: int, clean: NDArray[np.uint64], zbits: NDArray[np.uint64]) -> Guide:
    """The ``Guide`` of the in-tree grown in ``tree`` to ``limit`` (``run`` with no targets), with its
    nodes' path cells ``clean`` and the searched metric's cells ``zbits`` (``clean`` (0, W): no test)."""
    return Guide(
        np.zeros((3, 0), dtype=np.int64),
        np.zeros((0, 0), dtype=np.int64),
        tree.cost,
        tree.tie1,
        tree.tie2,
        tree.state,
        limit + 1,
        clean,
        zbits,
    )


@compiled_inline
def _potential(gd: Guide, tl: NDArray[np.int64], v: int, h: int) -> tuple[int, int, int]:
    """``guided``'s potential of kept node ``h`` (original node ``v``); ``tl`` is the target's row of the
    landmark table (empty: no landmarks). An in-tree's potential is its label where it settled ``h``, else
    ``(cutoff, 0, 0)``: no more than any unsettled node's label, and within one super-edge's cost of
    every settled node's (each settled label is below ``cutoff``), so it never drops along a super-edge by
    more than the super-edge's label under a metric no cheaper than the in-tree's."""
    if tl.shape[0] > 0:
        return _bound(gd.lm, tl, v), 0, 0
    if gd.tree_state.shape[0] > 0:
        if gd.tree_state[h] == -2:
            return gd.tree_cost[h], gd.tree_tie1[h], gd.tree_tie2[h]
        return gd.cutoff, 0, 0
    return gd.pot[0, h], gd.pot[1, h], gd.pot[2, h]


@compiled
def run_guided(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    source: int,
    target: int,
    pot: NDArray[np.int64],
    ws: Workspace,
    lm: NDArray[np.int64],
) -> None:
    """``guided`` with the potential ``pot`` or the landmark table ``lm`` (shape (0, 0): none), the metric
    held in ``costs``."""
    none = np.zeros(0, dtype=np.int64)
    bits = np.zeros((0, CLEAN_WORDS), dtype=np.uint64)
    gd = Guide(pot, lm, none, none, none, none, 0, bits, np.zeros(CLEAN_WORDS, dtype=np.uint64))
    guided(g, ed, costs, source, target, ws, gd, no_lazy())


@compiled_inline
def _guided_seed(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    ws: Workspace,
    gd: Guide,
    tl: NDArray[np.int64],
    source: int,
    n_touched: int,
) -> tuple[int, int]:
    """Queue the first labels of a guided search from ``source`` (keyed by label + potential); returns the
    queue's size and the touched nodes' count."""
    cost, tie1, tie2, state = ws.cost, ws.tie1, ws.tie2, ws.state
    sk = g.kept_of[source]
    size = 0
    for j in range(1 if sk >= 0 else 2):
        h, c, a, b, s, os = _seed(g, ed, costs.edge, source, sk, j)
        if h < 0:
            continue
        p0, p1, p2 = _potential(gd, tl, g.kept[h], h)
        if p0 >= INF or not _less(c, a, b, cost[h], tie1[h], tie2[h]):
            continue
        if cost[h] == INF and not ws.need[h]:
            ws.touched[n_touched] = h
            n_touched += 1
        cost[h] = c
        tie1[h] = a
        tie2[h] = b
        ws.pse[h] = s
        ws.pstart[h] = os
        at = state[h]
        if at < 0:
            at = size
            size += 1
        _guided_up(ws.nxt, ws.hkey, state, at, h, c + p0, a + p1, b + p2)
    return size, n_touched


@compiled_inline
def _meets(gd: Guide, k: int) -> bool:
    """``guided`` stops at kept node ``k`` (just settled) when ``gd`` holds an in-tree's path cells and
    ``k``'s in-tree path enters none of the cells ``gd.zbits`` holds: that path costs the searched metric
    what it costs the in-tree's, and no other path from ``k`` costs less (the metric is nowhere cheaper
    than the in-tree's), so ``k``'s key -- its label plus that path's label -- is the label of a path to
    the target; no key taken later is smaller, so it is the target's label, and the canonical path is the
    one to ``k`` (``unfold``) followed by the in-tree's path from ``k``."""
    if gd.clean.shape[0] == 0 or gd.tree_state[k] != -2:
        return False
    hit = np.uint64(0)
    for w in range(gd.zbits.shape[0]):
        hit |= gd.clean[k, w] & gd.zbits[w]
    return bool(hit == 0)


@compiled
def guided(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    source: int,
    target: int,
    ws: Workspace,
    gd: Guide,
    lazy: Lazy,
) -> int:
    """The canonical path from ``source`` to ``target`` as ``run`` finds it, searched goal-directed (A*).

    The potential (``Guide``) is a label per kept node, ``(cost, tie1, tie2)`` (cost ``INF``: the node
    cannot reach the target), that never drops by more than a super-edge's label along it:
    ``pot[:, u] <= label(u, v) + pot[:, v]`` lexicographically. The labels to the target under any metric no
    dearer on any edge are one (a lexicographic shortest-path label obeys the triangle inequality). Nodes
    are taken in the order of label + potential, compared lexicographically: along a super-edge that key
    never decreases, so the order is a plain Dijkstra's on those keys, and since the potential is the
    same for every path to a node, each node's label -- read with ``resolve`` and ``unfold`` as after
    ``run`` -- is the one ``run`` gives it. With the labels of the cheaper metric as potential, a search
    whose metric differs from it nowhere on the canonical path goes straight along that path. The search
    stops when the target can be resolved and settles no node that cannot reach it. ``lazy``: as in
    ``grow``. Returns -1, or the kept node where it stopped before the target (``_meets``).
    """
    cost, tie1, tie2, state, heap, hkey = ws.cost, ws.tie1, ws.tie2, ws.state, ws.nxt, ws.hkey
    _reset(ws)
    se_cost = costs.se
    lazy_on, fixed, zmask, term, umax, kappa = (
        lazy.on,
        lazy.fixed,
        lazy.zmask,
        lazy.term,
        lazy.umax,
        lazy.kappa,
    )
    se_ptr, se_edges, ec_ptr, ec_cell, time_s = g.se_ptr, g.se_edges, ed.ec_ptr, ed.ec_cell, ed.time_s
    ws.info[0] = source
    tgt = np.full(1, target, dtype=np.int64)
    n_touched, remaining = _need_targets(g, source, tgt, ws)
    tl = gd.lm[target] if gd.lm.shape[0] > 0 else np.zeros(0, dtype=np.int64)
    if lazy.on:
        _lazy_ends(g, ed, costs, lazy, source, tgt)
    size = 0
    if remaining > 0:
        size, n_touched = _guided_seed(g, ed, costs, ws, gd, tl, source, n_touched)
    complete, meet = 1, -1
    while size > 0:
        k = heap[0]
        size = _guided_pop(heap, hkey, state, size)
        state[k] = -2
        if ws.need[k]:
            remaining -= 1
            if remaining == 0:
                complete = 0
                break
        if _meets(gd, k):
            complete, meet = 0, k
            break
        d = cost[k]
        a0 = tie1[k]
        b0 = tie2[k]
        for s in range(g.indptr[k], g.indptr[k + 1]):
            h = g.se_head[s]
            st = state[h]
            if st == -2:
                continue
            p0, p1, p2 = _potential(gd, tl, g.kept[h], h)
            if p0 >= INF:
                continue
            if not lazy_on:
                c = d + se_cost[s]
            elif fixed[s] >= 0:
                c = d + fixed[s]
            else:
                c = d + _crossing_cost(se_ptr, se_edges, ec_ptr, ec_cell, time_s, zmask, term, umax, kappa, s)
            a = a0 + g.se_tie1[s]
            b = b0 + g.se_tie2[s]
            if _less(c, a, b, cost[h], tie1[h], tie2[h]):
                if cost[h] == INF and not ws.need[h]:
                    ws.touched[n_touched] = h
                    n_touched += 1
                cost[h] = c
                tie1[h] = a
                tie2[h] = b
                ws.pse[h] = s
                ws.pstart[h] = 0
                at = st
                if at < 0:
                    at = size
                    size += 1
                _guided_up(heap, hkey, state, at, h, c + p0, a + p1, b + p2)
    ws.info[1] = complete
    ws.info[2] = n_touched
    return meet


@compiled
def resolve(
    g: SearchGraph, ed: Edges, costs: Costs, limit: int, v: int, ws: Workspace
) -> tuple[int, int, int, int, int]:
    """The label of node ``v`` after ``run``: ``(cost, tie1, tie2, super-edge, start offset)``.

    A kept node reads its own label; an interior node takes the best of arriving along each super-edge it
    lies on (from the chain's tail, or from the source when it lies before ``v`` on that chain). Cost is
    ``INF`` when ``v`` is not reached within ``limit`` or cannot be decided because the search stopped
    early. The source itself is ``(0, 0, 0, -1, 0)``.
    """
    source = ws.info[0]
    if v == source:
        return 0, 0, 0, -1, 0
    kv = g.kept_of[v]
    if kv >= 0:
        if ws.state[kv] != -2:
            return INF, 0, 0, -1, 0
        return ws.cost[kv], ws.tie1[kv], ws.tie2[kv], ws.pse[kv], ws.pstart[kv]
    sk = g.kept_of[source]
    best_c = INF
    best_a = 0
    best_b = 0
    best_s = -1
    best_start = 0
    for j in range(2):
        s = g.pos_se[v, j]
        if s < 0:
            continue
        off = g.pos_off[v, j]
        os = _offset_on(g.pos_se, g.pos_off, source, s) if sk < 0 else -1
        if os >= 0 and os < off:
            start = os
            c = 0
            a = 0
            b = 0
        else:
            t = g.se_tail[s]
            if ws.state[t] != -2:
                if ws.info[1] == 0:
                    return INF, 0, 0, -1, 0  # the tail may still be near: undecided
                continue
            start = 0
            c = ws.cost[t]
            a = ws.tie1[t]
            b = ws.tie2[t]
        for p in range(g.se_ptr[s] + start, g.se_ptr[s] + off):
            e = g.se_edges[p]
            c += costs.edge[e]
            a += ed.tie1[e]
            b += ed.tie2[e]
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
def unfold(g: SearchGraph, ed: Edges, costs: Costs, limit: int, v: int, ws: Workspace) -> bool:
    """Write ``ws.pred`` for every original node on the tree path to ``v``; False if ``v`` is not reached."""
    c, _a, _b, s, start = resolve(g, ed, costs, limit, v, ws)
    if c >= INF:
        return False
    if v == ws.info[0]:
        return True
    kv = g.kept_of[v]
    if kv < 0:  # interior: the prefix of its super-edge up to it, then on from the tail
        off = _offset_on(g.pos_se, g.pos_off, v, s)
        for p in range(g.se_ptr[s] + start, g.se_ptr[s] + off):
            ws.pred[g.se_node[p]] = g.se_edges[p]
        if start != 0:
            return True
        kv = g.se_tail[s]
    _unfold_from(g.se_ptr, g.se_node, g.se_edges, g.se_tail, ws.pse, ws.pstart, ws.unfolded, ws.pred, kv)
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
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    limit: int,
    nodes: NDArray[np.int64],
    ws: Workspace,
    reached: NDArray[np.bool_],
) -> bool:
    """``unfold`` every one of ``nodes`` (``reached[i]``: node ``i`` was); True when all were.

    One call for many nodes: numba counts a reference for every array of every tuple passed to a compiled
    function, about 0.7-1.7 us per ``resolve`` or ``unfold`` call with the graph, metric and workspace passed
    whole, several times the work of unfolding a node; here a kept node is unfolded from the arrays alone."""
    source = ws.info[0]
    state = ws.state
    all_reached = True
    for i in range(nodes.shape[0]):
        v = nodes[i]
        kv = g.kept_of[v]
        if kv >= 0 and v != source:
            ok = state[kv] == -2
            if ok:
                _unfold_from(
                    g.se_ptr, g.se_node, g.se_edges, g.se_tail, ws.pse, ws.pstart, ws.unfolded, ws.pred, kv
                )
        else:
            ok = unfold(g, ed, costs, limit, v, ws)
        reached[i] = ok
        all_reached = all_reached and ok
    return all_reached


@compiled
def labels(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    limit: int,
    nodes: NDArray[np.int64],
    ws: Workspace,
    out: NDArray[np.int64],
) -> None:
    """``resolve``'s label ``(cost, tie1, tie2)`` of every one of ``nodes`` into ``out[:, i]`` in one call
    (see ``unfold_many``)."""
    source = ws.info[0]
    for i in range(nodes.shape[0]):
        v = nodes[i]
        kv = g.kept_of[v]
        if kv >= 0 and v != source:
            if ws.state[kv] == -2:
                out[0, i] = ws.cost[kv]
                out[1, i] = ws.tie1[kv]
                out[2, i] = ws.tie2[kv]
            else:
                out[0, i] = INF
                out[1, i] = 0
                out[2, i] = 0
        else:
            c, a, b, _s, _start = resolve(g, ed, costs, limit, v, ws)
            out[0, i] = c
            out[1, i] = a
            out[2, i] = b


@compiled
def path_to(ed: Edges, towards: int, pred: NDArray[np.int64], source: int, v: int) -> NDArray[np.int64]:
    """Edges of the unfolded tree path between the root ``source`` and ``v``, in travel order: from
    ``source`` to ``v`` in a forward tree (``towards`` 1), from ``v`` to ``source`` in a reverse one."""
    count = 0
    x = v
    while x != source:
        e = pred[x]
        count += 1
        x = ed.tail[e] if towards == 1 else ed.head[e]
    out = np.empty(count, dtype=np.int64)
    x = v
    for i in range(count):
        e = pred[x]
        if towards == 1:
            out[count - 1 - i] = e
            x = ed.tail[e]
        else:
            out[i] = e
            x = ed.head[e]
    return out


@compiled
def walk(ed: Edges, succ: NDArray[np.int64], start: int, root: int) -> NDArray[np.int64]:
    """Edges from ``start`` to ``root`` following a reverse tree's ``succ`` (original edge ids)."""
    return path_to(ed, 0, succ, root, start)


@compiled
def tree(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    queries: NDArray[np.int64],
    ws: Workspace,
    out_cost: NDArray[np.int64],
) -> None:
    """``run`` then ``unfold`` every query; ``out_cost[i]`` is query ``i``'s cost (``INF`` unreached)."""
    run(g, ed, costs, source, limit, targets, ws)
    for i in range(queries.shape[0]):
        if unfold(g, ed, costs, limit, queries[i], ws):
            out_cost[i] = resolve(g, ed, costs, limit, queries[i], ws)[0]
        else:
            out_cost[i] = INF


@compiled
def paths(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    ws: Workspace,
    sources: NDArray[np.int64],
    targets: NDArray[np.int64],
    lm: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The canonical path of every (source, target) pair in one call, as CSR ``(ptr, edges)``; a pair that
    cannot be joined gets ``ptr`` -1 at its end (``ptr[i + 1] == -1``). With a landmark table ``lm``
    (``landmarks``; ``costs`` must be the travel time, or dearer) each search is goal-directed
    (``run_guided``; the same paths); shape (0, 0): plain searches."""
    n = sources.shape[0]
    ptr = np.zeros(n + 1, dtype=np.int64)
    flat = np.empty(max(64, 32 * n), dtype=np.int64)
    used = 0
    tgt = np.empty(1, dtype=np.int64)
    guided = lm.shape[0] > 0
    pot = np.empty((3, 0), dtype=np.int64)
    for i in range(n):
        if guided:
            run_guided(g, ed, costs, sources[i], targets[i], pot, ws, lm)
        else:
            tgt[0] = targets[i]
            run(g, ed, costs, sources[i], INF, tgt, ws)
        if not unfold(g, ed, costs, INF, targets[i], ws):
            ptr[i + 1] = -1
            return ptr, flat[:used]
        flat, used = append_path(flat, used, path_to(ed, g.towards, ws.pred, sources[i], targets[i]))
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


def fastest_paths(
    graph: RoadGraph, ws: Workspace, sources: NDArray[np.int64], targets: NDArray[np.int64]
) -> list[NDArray[np.int64]]:
    """The canonical fastest path of every (source, target) pair (one compiled call).

    Raises
    ------
    ValueError
        When a target cannot be reached from its source.
    """
    src = np.asarray(sources, dtype=np.int64)
    tgt = np.asarray(targets, dtype=np.int64)
    ptr, flat = paths(graph.forward, graph.edges, graph.time_forward, ws, src, tgt, landmarks(graph))
    return split_paths(ptr, flat, src, tgt)


def fastest_path(graph: RoadGraph, ws: Workspace, source: int, target: int) -> NDArray[np.int64]:
    """Edges of the canonical fastest path from ``source`` to ``target`` (forward workspace ``ws``).

    Raises
    ------
    ValueError
        When ``target`` cannot be reached.
    """
    return path(graph, ws, graph.time_forward, source, target)


def path(graph: RoadGraph, ws: Workspace, costs: Costs, source: int, target: int) -> NDArray[np.int64]:
    """Edges of the canonical shortest path from ``source`` to ``target`` under ``costs`` (forward).

    Raises
    ------
    ValueError
        When ``target`` cannot be reached.
    """
    ed = graph.edges
    tgt = np.array([target], dtype=np.int64)
    out = np.zeros(1, dtype=np.int64)
    tree(graph.forward, ed, costs, int(source), int(INF), tgt, tgt, ws, out)
    if out[0] >= INF:
        raise ValueError(f"node {target} cannot be reached from node {source}")
    edges: NDArray[np.int64] = path_to(ed, 1, ws.pred, int(source), int(target))
    return edges


LANDMARKS = 8
"""Landmarks per city for the goal-directed point-to-point searches (``landmarks``)."""

_landmarks: weakref.WeakKeyDictionary[RoadGraph, NDArray[np.int64]] = weakref.WeakKeyDictionary()
_landmarks_lock = threading.Lock()


def landmarks(graph: RoadGraph, count: int = LANDMARKS) -> NDArray[np.int64]:
    """The travel times between every node and ``count`` landmarks, as ``(n, 2 count)``: column ``i`` from
    the node to landmark ``i``, column ``count + i`` from landmark ``i`` to the node (``INF``: no path);
    built once per graph. Landmarks are picked farthest first (each the node farthest, there and back,
    from the ones before, starting from node 0's farthest), so that for most pairs one lies beyond the
    target and its bound (``_bound``) is close to the true time (the "ALT" bounds of Goldberg and
    Harrelson, 2005). Only speed depends on the choice."""
    count = min(count, graph.n_nodes)
    with _landmarks_lock:
        table = _landmarks.get(graph)
        if table is None or table.shape[1] != 2 * count:
            table = _landmarks[graph] = _landmark_table(graph, count)
        return table


def _landmark_table(graph: RoadGraph, count: int) -> NDArray[np.int64]:
    n = graph.n_nodes
    nodes = np.arange(n, dtype=np.int64)
    table = np.full((n, 2 * count), INF, dtype=np.int64)
    wf, wr = workspace(graph), workspace(graph, reverse=True)
    out = np.empty((3, n), dtype=np.int64)
    empty = np.zeros(0, dtype=np.int64)

    def there_and_back(v: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        run(graph.reverse, graph.edges, graph.time_reverse, v, INF, empty, wr)
        labels(graph.reverse, graph.edges, graph.time_reverse, INF, nodes, wr, out)
        to_v = out[0].copy()
        run(graph.forward, graph.edges, graph.time_forward, v, INF, empty, wf)
        labels(graph.forward, graph.edges, graph.time_forward, INF, nodes, wf, out)
        return to_v, out[0].copy()

    to0, from0 = there_and_back(0)
    spread = np.where((to0 < INF) & (from0 < INF), to0 + from0, -1)  # nodes that reach 0 and back
    for i in range(count):
        v = int(np.argmax(spread))
        table[:, i], table[:, count + i] = there_and_back(v)
        there, back = table[:, i], table[:, count + i]
        both = np.where((there < INF) & (back < INF), there + back, -1)
        spread = both if i == 0 else np.minimum(spread, both)
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
