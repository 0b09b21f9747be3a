"""The guided (A*) search: point-to-point searches toward one target under a potential, either the
landmarks' lower bounds (``_bound``) or an in-tree's labels (:class:`Guide`), with the cells its path
crosses. Same labels and tie rule as ``services.network.dijkstra``; the same canonical paths.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network.dijkstra import _label, _lazy_ends, _need_targets, _seed, crossing_cost
from services.network.graph import (
    INF,
    Costs,
    Edges,
    Lazy,
    SearchGraph,
    no_lazy,
)
from services.network.heaps import Workspace, _less, _offset_on, _reset

__all__ = [
    "Guide",
    "CLEAN_WORDS",
    "cell_bit",
    "tree_guide",
    "run_guided",
    "potential_guide",
    "guided",
]


# The binary heap of guided's queue: ``heap[i]`` the node at position ``i``, ``hkey[i]`` its key beside it
# (a comparison reads one row), ``state[k]`` node ``k``'s position. Its steps are compiled functions that
# guided's loop calls, not inlined ones: numba's inlining counts a reference to each array an inlined call
# takes, every time it runs, where a call lends them (800 landmark-guided searches on a 22,500-node grid:
# 1.3 times as long with these steps inlined; the landmarks' bound, called the same way, timed the same
# either way). The steps write entries in place; none returns early, since a compiled function that does
# counts a reference to each array it takes on every call (numba's reference pruning leaves them).


@compiled
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
    no larger than before) and sift it up."""
    while i > 0:
        p = (i - 1) >> 1
        if not _less(c, a, b, hkey[p, 0], hkey[p, 1], hkey[p, 2]):
            break
        q = heap[p]
        heap[i] = q
        hkey[i, 0], hkey[i, 1], hkey[i, 2] = hkey[p, 0], hkey[p, 1], hkey[p, 2]
        state[q] = i
        i = p
    heap[i] = k
    hkey[i, 0], hkey[i, 1], hkey[i, 2] = c, a, b
    state[k] = i


@compiled
def _enqueue(
    heap: NDArray[np.int64],
    hkey: NDArray[np.int64],
    state: NDArray[np.int64],
    size: int,
    k: int,
    c: int,
    a: int,
    b: int,
) -> int:
    """Queue node ``k`` with key ``(c, a, b)``, or move it up to that key if queued; the queue's new size."""
    at = state[k]
    if at < 0:
        at = size
        size += 1
    _guided_up(heap, hkey, state, at, k, c, a, b)
    return size


@compiled
def _guided_down(
    heap: NDArray[np.int64], hkey: NDArray[np.int64], state: NDArray[np.int64], size: int
) -> None:
    """The root of the binary heap just taken out and the queue's size down to ``size`` (at least 1): put its
    last entry (position ``size``) at the root and sift it down. (No early return: numba counts a reference
    to each array a compiled function with one takes, on every call.)"""
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
        q = heap[c]
        heap[i] = q
        hkey[i, 0], hkey[i, 1], hkey[i, 2] = hkey[c, 0], hkey[c, 1], hkey[c, 2]
        state[q] = i
        i = c
    heap[i] = k
    hkey[i, 0], hkey[i, 1], hkey[i, 2] = c0, c1, c2
    state[k] = i


@compiled
def _bound(landmarks: NDArray[np.int64], target_row: NDArray[np.int64], v: int) -> int:
    """The landmarks' lower bound on the travel time from node ``v`` to the target whose row is ``target_row``
    (``landmarks``): ``d(v, L) - d(t, L)`` and ``d(L, t) - d(L, v)`` by the triangle inequality, the largest
    over the landmarks (at least 0); ``INF`` when ``v`` cannot reach a landmark the target reaches, so
    cannot reach the target. Each term grows along an edge by at most the edge's time, so the largest
    does too: a potential for ``run_guided``."""
    n = target_row.shape[0] // 2
    best = 0
    for i in range(n):
        to_t = target_row[i]
        if to_t < INF:
            to_v = landmarks[v, i]
            if to_v >= INF:
                return INF
            if to_v - to_t > best:
                best = to_v - to_t
        from_t = target_row[n + i]
        from_v = landmarks[v, n + i]
        if from_t < INF and from_v < INF and from_t - from_v > best:
            best = from_t - from_v
    return best


class Guide(NamedTuple):
    """Where ``guided`` reads its potential: a landmark table ``lm`` (n, 2L) (``landmarks``; the travel-time
    bound, ties 0) when it has rows, else an in-tree's labels, the arrays of the reverse workspace it was
    grown in (``tree_*``, (K,) each: kept indices are the same both ways), grown to ``cutoff - 1`` and not
    stopped early, so that a node it did not settle costs at least ``cutoff`` (``potential_guide``: any
    label per kept node, every node settled).

    With an in-tree, ``clean`` (K, ``CLEAN_WORDS``) holds the cells each settled node's in-tree path enters,
    written when the search first asks (``_cells_up``: the reverse graph's super-edges ``up_*``, the
    in-tree's ``tree_pse`` and ``tree_pstart``; ``done[k] == stamp`` marks node ``k`` written, ``stack``
    is scratch of K entries), and ``zbits`` the cells whose entering edges the searched metric prices
    differently from the in-tree's (as ``cell_bit`` sets; ``clean`` of shape (0, W): no such test)."""

    lm: NDArray[np.int64]
    tree_cost: NDArray[np.int64]
    tree_tie1: NDArray[np.int64]
    tree_tie2: NDArray[np.int64]
    tree_state: NDArray[np.int64]
    cutoff: int
    clean: NDArray[np.uint64]
    zbits: NDArray[np.uint64]
    tree_pse: NDArray[np.int64]
    tree_pstart: NDArray[np.int64]
    up_tail: NDArray[np.int64]
    up_ptr: NDArray[np.int64]
    up_edges: NDArray[np.int64]
    done: NDArray[np.int64]
    stamp: int
    stack: NDArray[np.int64]


CLEAN_WORDS = 4
"""Words of a cell set (``cell_bit``; ``guided`` reads the four by name): cell ``c`` is bit
``c % (64 * CLEAN_WORDS)``, so on a network of more cells two cells may share a bit (a set then holds
more cells than it should, never fewer)."""


@compiled_inline
def cell_bit(bits: NDArray[np.uint64], c: int) -> None:
    """Add cell ``c`` to the cell set ``bits`` (``CLEAN_WORDS`` words)."""
    b = c % (64 * CLEAN_WORDS)
    bits[b >> 6] |= np.uint64(1) << np.uint64(b & 63)


@compiled_inline
def _cells_up(
    clean: NDArray[np.uint64],
    done: NDArray[np.int64],
    stamp: int,
    stack: NDArray[np.int64],
    walk: tuple[
        NDArray[np.int64],
        NDArray[np.int64],
        NDArray[np.int64],
        NDArray[np.int64],
        NDArray[np.int64],
        NDArray[np.int64],
        NDArray[np.int64],
    ],
    k0: int,
) -> None:
    """Write ``clean[k]`` for kept node ``k0`` the in-tree settled, and for the nodes on its tree path not
    written yet (``done[k] != stamp``): the cells the path to the root enters (each edge's cells but its
    first), as a ``cell_bit`` set, each node's from the next node's toward the root. ``walk``: the in-tree's
    ``pse`` and ``pstart``, the reverse graph's ``se_tail``, ``se_ptr`` and ``se_edges``, the edges'
    ``ec_ptr`` and ``ec_cell``; ``stack``: scratch of K entries."""
    pse, pstart, up_tail, up_ptr, up_edges, ec_ptr, ec_cell = walk
    top = 0
    k = k0
    while True:  # toward the root, to a node written or the root's super-edge
        stack[top] = k
        top += 1
        s = pse[k]
        if s < 0 or pstart[k] != 0:
            break
        k = up_tail[s]
        if done[k] == stamp:
            break
    while top > 0:
        top -= 1
        k = stack[top]
        s = pse[k]
        for w in range(CLEAN_WORDS):
            clean[k, w] = 0
        if s >= 0:
            start = pstart[k]
            if start == 0:
                nxt = up_tail[s]
                for w in range(CLEAN_WORDS):
                    clean[k, w] = clean[nxt, w]
            for p in range(up_ptr[s] + start, up_ptr[s + 1]):
                e = up_edges[p]
                for j in range(ec_ptr[e] + 1, ec_ptr[e + 1]):
                    cell_bit(clean[k], ec_cell[j])
        done[k] = stamp


@compiled
def tree_guide(
    graph: SearchGraph,
    tree: Workspace,
    limit: int,
    cells: tuple[NDArray[np.uint64], NDArray[np.int64], NDArray[np.int64]],
    stamp: int,
    zbits: NDArray[np.uint64],
) -> Guide:
    """The ``Guide`` of the in-tree grown in ``tree`` on the reverse graph ``graph`` to ``limit`` (``run``
    with no targets), the searched metric's cells ``zbits``, and ``cells`` = (clean, done, stack) where its
    nodes' path cells are written on demand under ``stamp`` (a stamp new for each in-tree; ``clean`` of
    shape (0, W): no test)."""
    clean, done, stack = cells
    return Guide(
        np.zeros((0, 0), dtype=np.int64),
        tree.cost,
        tree.tie1,
        tree.tie2,
        tree.state,
        limit + 1,
        clean,
        zbits,
        tree.pse,
        tree.pstart,
        graph.se_tail,
        graph.se_ptr,
        graph.se_edges,
        done,
        stamp,
        stack,
    )


@compiled_inline
def _potential(guide: Guide, target_row: NDArray[np.int64], v: int, h: int) -> tuple[int, int, int]:
    """``guided``'s potential of kept node ``h`` (original node ``v``); ``target_row`` is the target's row of
    the landmark table (empty: no landmarks). An in-tree's potential is its label where it settled ``h``, else
    ``(cutoff, 0, 0)``: no more than any unsettled node's label, and within one super-edge's cost of every
    settled node's (each settled label is below ``cutoff``), so it never drops along a super-edge by more than
    the super-edge's label under a metric no cheaper than the in-tree's. ``guided``'s loop reads the same
    from the guide's arrays taken out before it: a call per relaxation that takes the guide counts a
    reference to each of its arrays (2.6 times as long for landmark-guided searches)."""
    if target_row.shape[0] > 0:
        return _bound(guide.lm, target_row, v), 0, 0
    if guide.tree_state[h] == -2:
        return guide.tree_cost[h], guide.tree_tie1[h], guide.tree_tie2[h]
    return guide.cutoff, 0, 0


@compiled
def run_guided(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    source: int,
    target: int,
    pot: NDArray[np.int64],
    workspace: Workspace,
    landmarks: NDArray[np.int64],
) -> None:
    """``guided`` with the potential ``pot`` or the landmark table ``landmarks`` (shape (0, 0): none), the
    metric held in ``costs``."""
    guided(graph, edges, costs, source, target, workspace, potential_guide(pot, landmarks), no_lazy())


@compiled
def potential_guide(pot: NDArray[np.int64], landmarks: NDArray[np.int64]) -> Guide:
    """The ``Guide`` of the potential ``pot`` ((3, K), a label per kept node; shape (3, 0) with a table) or
    the landmark table ``landmarks`` (shape (0, 0): none), with no cell test."""
    none = np.zeros(0, dtype=np.int64)
    settled = np.full(pot.shape[1], -2, dtype=np.int64)
    bits = np.zeros((0, CLEAN_WORDS), dtype=np.uint64)
    zbits = np.zeros(CLEAN_WORDS, dtype=np.uint64)
    return Guide(
        landmarks,
        pot[0],
        pot[1],
        pot[2],
        settled,
        INF,
        bits,
        zbits,
        none,
        none,
        none,
        none,
        none,
        none,
        0,
        none,
    )


@compiled_inline
def _guided_label(
    workspace: Workspace,
    h: int,
    label: tuple[int, int, int],
    s: int,
    os: int,
    pot: tuple[int, int, int],
    size: int,
    n_touched: int,
) -> tuple[int, int]:
    """Give kept node ``h`` the label ``(cost, tie1, tie2)`` through super-edge ``s`` (entered ``os`` edges
    in) and queue it, or move it up the queue, keyed by label + potential ``pot``; returns the queue's size
    and the touched nodes' count."""
    c, a, b = label
    if workspace.cost[h] == INF and not workspace.need[h]:
        workspace.touched[n_touched] = h
        n_touched += 1
    workspace.cost[h] = c
    workspace.tie1[h] = a
    workspace.tie2[h] = b
    workspace.pse[h] = s
    workspace.pstart[h] = os
    at = workspace.state[h]
    if at < 0:
        at = size
        size += 1
    _guided_up(workspace.nxt, workspace.hkey, workspace.state, at, h, c + pot[0], a + pot[1], b + pot[2])
    return size, n_touched


@compiled_inline
def _guided_seed(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    workspace: Workspace,
    guide: Guide,
    target_row: NDArray[np.int64],
    source: int,
    n_touched: int,
) -> tuple[int, int]:
    """Queue the first labels of a guided search from ``source`` (keyed by label + potential); returns the
    queue's size and the touched nodes' count."""
    cost, tie1, tie2 = workspace.cost, workspace.tie1, workspace.tie2
    sk = graph.kept_of[source]
    size = 0
    for j in range(1 if sk >= 0 else 2):
        h, c, a, b, s, os = _seed(graph, edges, costs.edge, source, sk, j)
        if h < 0:
            continue
        p0, p1, p2 = _potential(guide, target_row, graph.kept[h], h)
        if p0 >= INF or not _less(c, a, b, cost[h], tie1[h], tie2[h]):
            continue
        size, n_touched = _guided_label(workspace, h, (c, a, b), s, os, (p0, p1, p2), size, n_touched)
    return size, n_touched


# guided's stop: ``guided`` may stop at kept node ``k`` (just settled) when its guide holds an in-tree's
# path cells ``clean`` (``Guide``) and ``k``'s in-tree path enters none of the cells ``zbits`` holds: that
# path costs the searched metric what it costs the in-tree's, and no other path from ``k`` costs less (the
# metric is nowhere cheaper than the in-tree's), so ``k``'s key -- its label plus that path's label --
# is the label of a path to the target. Every path whose last kept node is not settled yet costs at
# least that key (keys leave the queue in order); the others reach an interior target inside its chain,
# from the source in it or from a settled end of it, and are never queued. ``guided`` stops only where
# the key is better than the best of those (``_into_target``): then it is the target's label, and the
# canonical path is the one to ``k`` (``unfold``) followed by the in-tree's path from ``k``.
# (The test reads the words of the cell sets in place: a call that takes the arrays counts a reference to
# each per settled node.)


@compiled_inline
def _into_target(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    source: int,
    target: int,
    k: int,
    label: tuple[int, int, int],
    best: tuple[int, int, int],
) -> tuple[int, int, int]:
    """The better of ``best`` and the paths that reach the interior ``target`` along one of its super-edges
    from kept node ``k`` (its tail, settled with ``label``), or from the source inside it (``k`` -1, the
    source before the target): no search queues those paths (the target is no kept node; its label is
    read afterwards, ``unfolding.resolve``). ``costs`` holds the super-edges' edges' costs (under a lazy
    metric, once ``_lazy_ends`` has written them)."""
    best_c, best_a, best_b = best
    for j in range(2):
        s = graph.pos_se[target, j]
        if s < 0:
            continue
        start = 0
        if k < 0:
            start = _offset_on(graph.pos_se, graph.pos_off, source, s) if graph.kept_of[source] < 0 else -1
            if start < 0 or start >= graph.pos_off[target, j]:
                continue
            c, a, b = 0, 0, 0
        elif graph.se_tail[s] == k:
            c, a, b = label
        else:
            continue
        for p in range(graph.se_ptr[s] + start, graph.se_ptr[s] + graph.pos_off[target, j]):
            e = graph.se_edges[p]
            c += costs.edge[e]
            a += edges.tie1[e]
            b += edges.tie2[e]
        if _less(c, a, b, best_c, best_a, best_b):
            best_c, best_a, best_b = c, a, b
    return best_c, best_a, best_b


@compiled_inline
def _guided_start(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    workspace: Workspace,
    guide: Guide,
    lazy: Lazy,
    source: int,
    target: int,
) -> tuple[int, int, int, NDArray[np.int64], tuple[int, int, int]]:
    """Start ``guided``'s search: reset ``workspace``, mark the target, cost the lazy ends and queue the
    source's first labels (none when the target is already resolved). Returns the queue's size, the touched
    nodes' count, the number of nodes to settle, the target's landmark row (empty: no landmarks) and the label
    of the path from the source to the target inside their chain (``_into_target``; ``INF``: none, or no early
    stop to hold against it)."""
    _reset(workspace)
    workspace.info[0] = source
    tgt = np.full(1, target, dtype=np.int64)
    n_touched, remaining = _need_targets(graph, source, tgt, workspace)
    tl = guide.lm[target] if guide.lm.shape[0] > 0 else np.zeros(0, dtype=np.int64)
    if lazy.on:
        _lazy_ends(graph, edges, costs, lazy, source, tgt)
    size = 0
    direct = (INF, 0, 0)
    if remaining > 0:
        size, n_touched = _guided_seed(graph, edges, costs, workspace, guide, tl, source, n_touched)
        if guide.clean.shape[0] > 0 and graph.kept_of[target] < 0:
            direct = _into_target(graph, edges, costs, source, target, -1, direct, direct)
    return size, n_touched, remaining, tl, direct


# guided's order: the potential (``Guide``) is a label per kept node, ``(cost, tie1, tie2)`` (cost ``INF``:
# the node cannot reach the target), that never drops by more than a super-edge's label along it:
# ``pot[:, u] <= label(u, v) + pot[:, v]`` lexicographically. The labels to the target under any metric no
# dearer on any edge are one (a lexicographic shortest-path label obeys the triangle inequality). Nodes are
# taken in the order of label + potential, compared lexicographically: along a super-edge that key never
# decreases, so the order is a plain Dijkstra's on those keys, and since the potential is the same for every
# path to a node, each node's label -- read with ``resolve`` and ``unfold`` as after ``run`` -- is the one
# ``run`` gives it. With the labels of the cheaper metric as potential, a search whose metric differs from
# it nowhere on the canonical path goes straight along that path.


@compiled
def guided(
    graph: SearchGraph,
    edges: Edges,
    costs: Costs,
    source: int,
    target: int,
    workspace: Workspace,
    guide: Guide,
    lazy: Lazy,
) -> int:
    """The canonical path from ``source`` to ``target`` as ``run`` finds it, searched goal-directed (A*) in
    the order described above, stopped when the target can be resolved; it settles no node that cannot reach
    it. ``lazy``: as in ``grow``. Returns -1, or the kept node where it stopped before the target (guided's
    stop, above: where that node's key beats every path to an interior target found so far)."""
    cost, tie1, tie2, state = workspace.cost, workspace.tie1, workspace.tie2, workspace.state
    heap, hkey, need, se_cost = workspace.nxt, workspace.hkey, workspace.need, costs.se
    pse, pstart, touched = workspace.pse, workspace.pstart, workspace.touched
    lazy_on, fixed, zmask, term = lazy.on, lazy.fixed, lazy.zmask, lazy.term
    umax, kappa, se_ptr, se_edges = lazy.umax, lazy.kappa, graph.se_ptr, graph.se_edges
    ec_ptr, ec_cell, time_s = edges.ec_ptr, edges.ec_cell, edges.time_s
    size, n_touched, remaining, tl, found = _guided_start(
        graph, edges, costs, workspace, guide, lazy, source, target
    )
    watch = guide.clean.shape[0] > 0 and graph.kept_of[target] < 0
    t_cost, t_tie1, t_tie2, t_state = guide.tree_cost, guide.tree_tie1, guide.tree_tie2, guide.tree_state
    cutoff, clean, zbits = guide.cutoff, guide.clean, guide.zbits
    watch_cells, done, stamp, stack = clean.shape[0] > 0, guide.done, guide.stamp, guide.stack
    walk = (guide.tree_pse, guide.tree_pstart, guide.up_tail, guide.up_ptr, guide.up_edges, ec_ptr, ec_cell)
    z0, z1, z2, z3 = zbits[0], zbits[1], zbits[2], zbits[3]  # the cell set's words, as scalars in the loop
    indptr, se_head, se_tie1, se_tie2 = graph.indptr, graph.se_head, graph.se_tie1, graph.se_tie2
    use_lm, lm, kept = tl.shape[0] > 0, guide.lm, graph.kept
    complete, meet = 1, -1
    while size > 0:
        k, kc, ka, kb, size = heap[0], hkey[0, 0], hkey[0, 1], hkey[0, 2], size - 1
        if size > 0:
            _guided_down(heap, hkey, state, size)
        state[k] = -2
        if need[k]:
            remaining -= 1
            if remaining == 0:
                complete = 0
                break
        if watch_cells and t_state[k] == -2:  # may stop here (guided's stop, above)
            if done[k] != stamp:
                _cells_up(clean, done, stamp, stack, walk, k)
            hit = (clean[k, 0] & z0) | (clean[k, 1] & z1) | (clean[k, 2] & z2) | (clean[k, 3] & z3)
            if hit == 0 and _less(kc, ka, kb, found[0], found[1], found[2]):
                complete, meet = 0, k
                break
        if watch and need[k]:
            found = _into_target(graph, edges, costs, source, target, k, (cost[k], tie1[k], tie2[k]), found)
        d, a0, b0 = cost[k], tie1[k], tie2[k]
        for s in range(indptr[k], indptr[k + 1]):
            h = se_head[s]
            if state[h] == -2:
                continue
            if use_lm:
                p0, p1, p2 = _bound(lm, tl, kept[h]), 0, 0
            elif t_state[h] == -2:
                p0, p1, p2 = t_cost[h], t_tie1[h], t_tie2[h]
            else:
                p0, p1, p2 = cutoff, 0, 0
            if p0 >= INF:
                continue
            if not lazy_on:
                c = d + se_cost[s]
            elif fixed[s] >= 0:
                c = d + fixed[s]
            else:
                c = d + crossing_cost(se_ptr, se_edges, ec_ptr, ec_cell, time_s, zmask, term, umax, kappa, s)
            a, b = a0 + se_tie1[s], b0 + se_tie2[s]
            if _less(c, a, b, cost[h], tie1[h], tie2[h]):
                if cost[h] == INF and not need[h]:
                    touched[n_touched] = h
                    n_touched += 1
                _label(cost, tie1, tie2, pse, pstart, h, c, a, b, s)
                size = _enqueue(heap, hkey, state, size, h, c + p0, a + p1, b + p2)
    workspace.info[1] = complete
    workspace.info[2] = n_touched
    return meet
