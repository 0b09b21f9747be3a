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


@compiled
def crossing_cost(
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
    summed over its edges). A call, not inlined: inlined, numba would count a reference to six of its
    arrays each time it runs (twelve atomic operations per crossing super-edge); the searches pass it
    plain arrays, since a call that takes records counts a reference to each of their arrays."""
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
    touched, state, cost, ring, bits = (  # out of the record once: a read in the loop counts a reference
        workspace.touched,
        workspace.state,
        workspace.cost,
        workspace.ring,
        workspace.bits,
    )
    use_ring = costs.span <= ring.shape[0]
    for i in range(n_touched):
        k = touched[i]
        if state[k] == -3:  # reached from a node that stopped the search: not known to be final
            state[k] = -1
        elif state[k] >= 0 and use_ring:  # still queued: leave the ring empty for the next search
            b = (cost[k] // costs.width) % costs.span
            ring[b] = -1
            bits[b >> 6] = 0
    workspace.info[1] = complete
    workspace.info[2] = n_touched


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


# Every search of an epoch runs grow's loop (``_grow_loop``). Its arrays are taken from the records once per
# search, at the top, and the loop's helpers take plain arrays: numba counts a reference for every array it
# takes from a record, so a helper taking the records would take them again for every settled node. Even
# with plain arrays, an inlined helper may leave its arguments' reference counting in the loop (an atomic
# increment and decrement per array and call, which numba's reference pruning does not remove): taking a
# node from the ring, linking one into it and moving one between buckets are therefore written out in the
# loop (as inlined helpers, a tree bounded by the reach on the generated metropolis took 3.15 ms against
# 1.75 ms written out: ``bench.bench_search`` in both versions), and the super-edges' lazy costs are a call
# (``crossing_cost``), which lends its arrays.
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
    start = _grow_start(graph, edges, costs, source, limit, targets, workspace, lazy)
    n_touched, complete = _grow_loop(graph, edges, costs, workspace, lazy, limit, start)
    _grow_leave(workspace, costs, n_touched, complete)


@compiled
def _grow_loop(
    g: SearchGraph,
    ed: Edges,
    costs: Costs,
    ws: Workspace,
    lazy: Lazy,
    limit: int,
    start: tuple[int, int, int, int],
) -> tuple[int, int]:
    """``grow``'s loop on ``g``, ``ed``, ``ws`` from ``_grow_start``'s queue: (touched nodes, complete)."""
    cost, tie1, tie2, pse, pstart, state = ws.cost, ws.tie1, ws.tie2, ws.pse, ws.pstart, ws.state
    nxt, prv, ring, bits, need, touched = ws.nxt, ws.prv, ws.ring, ws.bits, ws.need, ws.touched
    indptr, se_head, se_tie1, se_tie2, dead_end = g.indptr, g.se_head, g.se_tie1, g.se_tie2, g.dead_end
    se_ptr, se_edges, ec_ptr, ec_cell, time_s = g.se_ptr, g.se_edges, ed.ec_ptr, ed.ec_cell, ed.time_s
    lazy_on, fixed, zmask, term = lazy.on, lazy.fixed, lazy.zmask, lazy.term
    umax, kappa, width, span, se_cost, complete = lazy.umax, lazy.kappa, costs.width, costs.span, costs.se, 1
    size, pos, n_touched, remaining = start
    use_ring, early = span <= ring.shape[0], remaining > 0  # remaining > 0: targets left to settle
    while size > 0:
        if use_ring:  # the first node of the lowest non-empty bucket, taken out (heaps._unlink)
            if ring[pos] < 0:
                pos = _next_bucket(bits, span, pos)
            k = ring[pos]
            z, ring[pos] = nxt[k], nxt[k]
            if z >= 0:
                prv[z] = -1
            else:
                bits[pos >> 6] &= ~(np.int64(1) << (pos & 63))
            size, d = size - 1, cost[k]
        else:
            k, d, size = prv[0], nxt[0], _pop(nxt, prv, state, size)
        state[k] = -2
        remaining -= 1 if need[k] else 0
        if need[k] and remaining == 0 and early:
            complete = 0
            break
        for s in range(indptr[k], indptr[k + 1]):
            h = se_head[s]
            st = state[h]
            if st == -2:
                continue
            c = d + (fixed[s] if lazy_on else se_cost[s])
            if lazy_on and fixed[s] < 0:
                c = d + crossing_cost(se_ptr, se_edges, ec_ptr, ec_cell, time_s, zmask, term, umax, kappa, s)
            a, b, ch = tie1[k] + se_tie1[s], tie2[k] + se_tie2[s], cost[h]
            if c > limit or not (c < ch or (c == ch and (a < tie1[h] or (a == tie1[h] and b < tie2[h])))):
                continue
            _label(cost, tie1, tie2, pse, pstart, h, c, a, b, s)
            if st == -1 and ch == INF and not need[h]:
                touched[n_touched] = h
                n_touched += 1
            if st == -1 and dead_end[h]:
                state[h] = -3  # its only way in is from k: settled once k's edges are done
            elif not use_ring and (st == -1 or (st >= 0 and c < ch)):
                _sift_up(nxt, prv, state, size if st == -1 else st, c, h)
                size += 1 if st == -1 else 0
            elif use_ring and (st == -1 or (st >= 0 and (ch // width) % span != (c // width) % span)):
                if st >= 0:  # out of its bucket (heaps._unlink)
                    bo, pv, z = (ch // width) % span, prv[h], nxt[h]
                    if pv >= 0:
                        nxt[pv] = z
                    else:
                        ring[bo] = z
                        if z < 0:
                            bits[bo >> 6] &= ~(np.int64(1) << (bo & 63))
                    if z >= 0:
                        prv[z] = pv
                else:
                    state[h], size = 0, size + 1
                bk = (c // width) % span  # first in its new bucket (heaps._link)
                first, nxt[h], prv[h], ring[bk] = ring[bk], ring[bk], -1, h
                if first >= 0:
                    prv[first] = h
                else:
                    bits[bk >> 6] |= np.int64(1) << (bk & 63)
        remaining, stop = _settle_dead_ends(indptr, se_head, state, need, k, remaining, early)
        if stop:
            complete = 0
            break
    return n_touched, complete
