"""Canonical shortest paths on a contracted search graph: the one Dijkstra (compiled; its wrappers for a
few point-to-point paths are ``point_to_point``'s).

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

The workspace and queues are in ``services.network.heaps``; reading results off a search in
``services.network.unfolding``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network.graph import (
    INF,
    Costs,
    Edges,
    Lazy,
    SearchGraph,
    kappa_cost,
    lazy_fill,
    no_lazy,
)
from services.network.heaps import (
    Workspace,
    _less,
    _link,
    _next_bucket,
    _offset_on,
    _pop,
    _reset,
    _sift_up,
    _unlink,
)

__all__ = [
    "run",
    "grow",
]


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
    interior targets' chains (``unfolding.resolve`` reads their edges' costs)."""
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
#
# Nodes are taken from a bucket queue of width ``costs.width`` (the cheapest super-edge): every label in the
# lowest non-empty bucket is final, because anything that could still improve it would come along a
# super-edge from a node of the same bucket and so cost at least one width more. Within a bucket the order
# does not matter. Metrics too spread for the ring use a 4-ary heap on the cost instead. With ``lazy.on``
# the metric is computed as the search goes (``graph.Lazy``): each super-edge when it is relaxed, the
# source's and the targets' chains edge by edge before the search starts; ``costs.width`` and
# ``costs.span`` must then bound every super-edge's cost from below and above.


@compiled_inline
def _grow_start(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    ws: Workspace,
    lazy: Lazy,
) -> tuple[int, int, int, int]:
    """Start ``grow``'s search: reset ``ws``, mark the targets, cost the lazy ends and queue the source's
    first labels (none when every target is already resolved). Returns the queue's size, the ring's first
    bucket being emptied (ring), the touched nodes' count and the number of nodes to settle."""
    _reset(ws)
    ws.info[0] = source
    n_touched, remaining = _need_targets(g, source, targets, ws)
    size, pos = 0, 0
    if lazy.on:
        _lazy_ends(g, ed, costs, lazy, source, targets)
    if not (targets.shape[0] > 0 and remaining == 0):
        size, n_touched = _grow_seed(g, ed, costs, ws, source, limit, n_touched)
        if costs.span <= ws.ring.shape[0] and size > 0:
            pos = _next_bucket(ws.bits, costs.span, 0)
    return size, pos, n_touched, remaining


@compiled_inline
def _ring_take(
    ring: NDArray[np.int64],
    bits: NDArray[np.int64],
    nxt: NDArray[np.int64],
    prv: NDArray[np.int64],
    span: int,
    pos: int,
) -> tuple[int, int]:
    """Take a node from the lowest non-empty bucket at or after ``pos``; returns it and its bucket."""
    k = ring[pos]
    if k < 0:
        pos = _next_bucket(bits, span, pos)
        k = ring[pos]
    _unlink(ring, bits, nxt, prv, pos, k)
    return k, pos


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
    that chain). ``ws`` is reset here; read the result with ``resolve`` and ``unfold``. The queue (a bucket
    ring, or a heap for spread metrics) and the lazy metric are described above."""
    cost, tie1, tie2, pse, pstart, state = ws.cost, ws.tie1, ws.tie2, ws.pse, ws.pstart, ws.state
    nxt, prv, ring, bits, need, touched = ws.nxt, ws.prv, ws.ring, ws.bits, ws.need, ws.touched
    indptr, se_head, se_tie1, se_tie2, dead_end = g.indptr, g.se_head, g.se_tie1, g.se_tie2, g.dead_end
    lazy_on, fixed, zmask, term = lazy.on, lazy.fixed, lazy.zmask, lazy.term
    se_ptr, se_edges, ec_ptr, ec_cell, time_s = g.se_ptr, g.se_edges, ed.ec_ptr, ed.ec_cell, ed.time_s
    umax, kappa, width, span, se_cost = lazy.umax, lazy.kappa, costs.width, costs.span, costs.se
    use_ring, early = span <= ring.shape[0], targets.shape[0] > 0
    size, pos, n_touched, remaining = _grow_start(g, ed, costs, source, limit, targets, ws, lazy)
    complete = 1
    while size > 0:
        if use_ring:
            k, pos = _ring_take(ring, bits, nxt, prv, span, pos)
            size -= 1
            d = cost[k]
        else:
            k, d = prv[0], nxt[0]
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
