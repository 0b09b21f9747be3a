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
def _need_targets(
    graph: SearchGraph, source: int, targets: NDArray[np.int64], workspace: Workspace
) -> tuple[int, int]:
    """Mark the kept nodes a search must settle before every target can be resolved: a kept target itself,
    for an interior target the tails of its super-edges (unless the source lies before it on one). Returns
    the number of nodes touched so far and of nodes to settle."""
    sk = graph.kept_of[source]
    n_touched = 0
    remaining = 0
    for t in targets:
        if t == source:
            continue
        kt = graph.kept_of[t]
        if kt >= 0:
            if not workspace.need[kt]:
                workspace.need[kt] = True
                workspace.touched[n_touched] = kt
                n_touched += 1
                remaining += 1
            continue
        for j in range(2):
            s = graph.pos_se[t, j]
            if s < 0:
                continue
            if sk < 0:
                os = _offset_on(graph.pos_se, graph.pos_off, source, s)
                if os >= 0 and os < graph.pos_off[t, j]:
                    continue  # reached from the source along this very super-edge
            kt = graph.se_tail[s]
            if not workspace.need[kt]:
                workspace.need[kt] = True
                workspace.touched[n_touched] = kt
                n_touched += 1
                remaining += 1
    return n_touched, remaining


@compiled_inline
def _seed(
    graph: SearchGraph, edges: Edges, edge_cost: NDArray[np.int64], source: int, sk: int, j: int
) -> tuple[int, int, int, int, int, int]:
    """The ``j``-th first label of a search from ``source``: ``(kept node, cost, tie1, tie2, super-edge,
    start offset)``; the source itself when it is kept (j = 0), else the head of the ``j``-th super-edge it
    lies on with the cost of the rest of that super-edge (kept node -1: no such super-edge)."""
    if sk >= 0:
        return sk, 0, 0, 0, -1, 0
    s = graph.pos_se[source, j]
    if s < 0:
        return -1, 0, 0, 0, -1, 0
    os = graph.pos_off[source, j]
    c = 0
    a = 0
    b = 0
    for p in range(graph.se_ptr[s] + os, graph.se_ptr[s + 1]):
        e = graph.se_edges[p]
        c += edge_cost[e]
        a += edges.tie1[e]
        b += edges.tie2[e]
    return graph.se_head[s], c, a, b, s, os


@compiled_inline
def _lazy_ends(
    graph: SearchGraph, edges: Edges, costs: Costs, lazy: Lazy, source: int, targets: NDArray[np.int64]
) -> None:
    """Cost, edge by edge, the super-edges a search's paths may start or end inside: the source's and the
    interior targets' chains (``unfolding.resolve`` reads their edges' costs)."""
    for j in range(2):
        if graph.kept_of[source] < 0 and graph.pos_se[source, j] >= 0:
            lazy_fill(graph, edges, costs, lazy, graph.pos_se[source, j])
        for t in targets:
            if graph.kept_of[t] < 0 and graph.pos_se[t, j] >= 0:
                lazy_fill(graph, edges, costs, lazy, graph.pos_se[t, j])


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
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    workspace: Workspace,
) -> None:
    """``grow`` with the metric held in ``costs``."""
    grow(graph, edges, costs, source, limit, targets, workspace, no_lazy())


@compiled_inline
def _grow_seed(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    workspace: Workspace,
    source: int,
    limit: int,
    n_touched: int,
) -> tuple[int, int]:
    """Queue the first labels of a search from ``source`` within ``limit`` (in the ring, or the heap when
    the metric is too spread for it); returns the queue's size and the touched nodes' count."""
    cost, tie1, tie2, state = workspace.cost, workspace.tie1, workspace.tie2, workspace.state
    ring, bits, nxt, prv = workspace.ring, workspace.bits, workspace.nxt, workspace.prv
    width, span = costs.width, costs.span
    use_ring = span <= ring.shape[0]
    sk = graph.kept_of[source]
    size = 0
    for j in range(1 if sk >= 0 else 2):
        h, c, a, b, s, os = _seed(graph, edges, costs.edge, source, sk, j)
        if h < 0 or c > limit:
            continue
        if not _less(c, a, b, cost[h], tie1[h], tie2[h]):
            continue
        if cost[h] == INF and not workspace.need[h]:
            workspace.touched[n_touched] = h
            n_touched += 1
        old = cost[h]
        cost[h] = c
        tie1[h] = a
        tie2[h] = b
        workspace.pse[h] = s
        workspace.pstart[h] = os
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
def _grow_leave(workspace: Workspace, costs: Costs, n_touched: int, complete: int) -> None:
    """Leave the workspace as the next search expects it: a node reached from one that stopped the search
    is not known to be final; the ring is left empty. Records whether the search was ``complete`` and the
    number of nodes it touched."""
    use_ring = costs.span <= workspace.ring.shape[0]
    for i in range(n_touched):
        k = workspace.touched[i]
        if workspace.state[k] == -3:  # reached from a node that stopped the search: not known to be final
            workspace.state[k] = -1
        elif workspace.state[k] >= 0 and use_ring:  # still queued: leave the ring empty for the next search
            b = (workspace.cost[k] // costs.width) % costs.span
            workspace.ring[b] = -1
            workspace.bits[b >> 6] = 0
    workspace.info[1] = complete
    workspace.info[2] = n_touched


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
#
# With targets the search stops as soon as every target can be resolved: a kept target is settled, and for
# an interior target both ends of its chain are (unless the source lies before it on that chain).


@compiled_inline
def _grow_start(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    workspace: Workspace,
    lazy: Lazy,
) -> tuple[int, int, int, int]:
    """Start ``grow``'s search: reset ``workspace``, mark the targets, cost the lazy ends and queue the
    source's first labels (none when every target is already resolved). Returns the queue's size, the ring's
    first bucket being emptied (ring), the touched nodes' count and the number of nodes to settle."""
    _reset(workspace)
    workspace.info[0] = source
    n_touched, remaining = _need_targets(graph, source, targets, workspace)
    size, pos = 0, 0
    if lazy.on:
        _lazy_ends(graph, edges, costs, lazy, source, targets)
    if not (targets.shape[0] > 0 and remaining == 0):
        size, n_touched = _grow_seed(graph, edges, costs, workspace, source, limit, n_touched)
        if costs.span <= workspace.ring.shape[0] and size > 0:
            pos = _next_bucket(workspace.bits, costs.span, 0)
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
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    source: int,
    limit: int,
    targets: NDArray[np.int64],
    workspace: Workspace,
    lazy: Lazy,
) -> None:
    """Grow the canonical shortest-path tree from ``source`` (all kept nodes with cost <= ``limit``), or until
    every one of ``targets`` can be resolved; the queue, the lazy metric and the stop are described above.
    ``workspace`` is reset here; read the result with ``resolve`` and ``unfold``."""
    cost, tie1, tie2, pse = workspace.cost, workspace.tie1, workspace.tie2, workspace.pse
    pstart, state, nxt, prv = workspace.pstart, workspace.state, workspace.nxt, workspace.prv
    ring, bits, need, touched = workspace.ring, workspace.bits, workspace.need, workspace.touched
    indptr, se_head, se_tie1, se_tie2 = graph.indptr, graph.se_head, graph.se_tie1, graph.se_tie2
    dead_end, se_ptr, se_edges = graph.dead_end, graph.se_ptr, graph.se_edges
    lazy_on, fixed, zmask, term = lazy.on, lazy.fixed, lazy.zmask, lazy.term
    ec_ptr, ec_cell, time_s = edges.ec_ptr, edges.ec_cell, edges.time_s
    umax, kappa, width, span, se_cost = lazy.umax, lazy.kappa, costs.width, costs.span, costs.se
    use_ring, early, complete = span <= ring.shape[0], targets.shape[0] > 0, 1
    size, pos, n_touched, remaining = _grow_start(
        graph, edges, costs, source, limit, targets, workspace, lazy
    )
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
    _grow_leave(workspace, costs, n_touched, complete)
