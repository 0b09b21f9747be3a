"""Compiled inner loops (numba): Dijkstra on CSR arrays, tree walks and exact path evaluation.

Everything here works on flat arrays only; ``routing`` and ``dispatch`` wrap it. Each function has one
job and is small enough to check by reading; ``tests/unit/test_kernels.py`` compares them with scipy and
with plain-Python reference implementations.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "dijkstra",
    "dijkstra_contracted",
    "tree_search",
    "walk_edges",
    "walk_succ",
    "distinct_cells",
    "crossings",
    "first_pairs",
    "eval_path",
    "eval_pairs",
    "eval_targets",
    "eval_tree",
    "entered_utility",
]

_NOPYTHON = {"cache": True, "nogil": True}


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def _heap_push(keys: NDArray[np.float64], vals: NDArray[np.int64], size: int, key: float, val: int) -> int:
    i = size
    keys[i] = key
    vals[i] = val
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= keys[i]:
            break
        keys[parent], keys[i] = keys[i], keys[parent]
        vals[parent], vals[i] = vals[i], vals[parent]
        i = parent
    return size + 1


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def _heap_pop(keys: NDArray[np.float64], vals: NDArray[np.int64], size: int) -> int:
    size -= 1
    keys[0] = keys[size]
    vals[0] = vals[size]
    i = 0
    while True:
        left = 2 * i + 1
        if left >= size:
            break
        child = left
        if left + 1 < size and keys[left + 1] < keys[left]:
            child = left + 1
        if keys[i] <= keys[child]:
            break
        keys[child], keys[i] = keys[i], keys[child]
        vals[child], vals[i] = vals[i], vals[child]
        i = child
    return size


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def dijkstra(
    indptr: NDArray[np.int64],
    head: NDArray[np.int32],
    cost: NDArray[np.float64],
    source: int,
    limit: float,
    targets: NDArray[np.int64],
    aux: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """Single-source shortest paths over CSR ``(indptr, head, cost)``.

    Stops when every node in ``targets`` is settled (all nodes when ``targets`` is empty) or when the
    next distance exceeds ``limit``. Returns ``dist`` (inf when not settled), ``pred_edge`` (the edge
    entering each settled node on its shortest path, -1 at the source and elsewhere) and the sum of the
    per-edge ``aux`` weights along each settled node's tree path (e.g. its length). Ties keep the first
    edge found (deterministic for a given CSR order).
    """
    n = indptr.shape[0] - 1
    dist = np.full(n, np.inf)
    pred = np.full(n, -1, dtype=np.int64)
    done = np.zeros(n, dtype=np.bool_)
    is_target = np.zeros(n, dtype=np.bool_)
    remaining = 0
    for t in targets:
        if not is_target[t]:
            is_target[t] = True
            remaining += 1
    m = head.shape[0]
    keys = np.empty(m + 1)
    vals = np.empty(m + 1, dtype=np.int64)
    size = _heap_push(keys, vals, 0, 0.0, source)
    tentative = np.full(n, np.inf)
    tentative[source] = 0.0
    acc = np.full(n, np.nan)
    acc_t = np.zeros(n)
    while size > 0:
        d = keys[0]
        u = vals[0]
        size = _heap_pop(keys, vals, size)
        if done[u]:
            continue
        if d > limit:
            break
        done[u] = True
        dist[u] = d
        acc[u] = acc_t[u]
        if is_target[u]:
            remaining -= 1
            if remaining == 0:
                break
        for e in range(indptr[u], indptr[u + 1]):
            v = head[e]
            nd = d + cost[e]
            if nd < tentative[v]:
                tentative[v] = nd
                pred[v] = e
                acc_t[v] = acc_t[u] + aux[e]
                size = _heap_push(keys, vals, size, nd, v)
    for v in range(n):
        if not done[v]:
            pred[v] = -1
    return dist, pred, acc


@numba.njit(inline="always", **_NOPYTHON)  # type: ignore[misc]
def _heap4_push(keys: NDArray[np.float64], vals: NDArray[np.int64], size: int, key: float, val: int) -> int:
    """Push onto a 4-ary min-heap (hole sifting); returns the new size."""
    i = size
    while i > 0:
        parent = (i - 1) >> 2
        pk = keys[parent]
        if pk <= key:
            break
        keys[i] = pk
        vals[i] = vals[parent]
        i = parent
    keys[i] = key
    vals[i] = val
    return size + 1


@numba.njit(inline="always", **_NOPYTHON)  # type: ignore[misc]
def _heap4_pop(keys: NDArray[np.float64], vals: NDArray[np.int64], size: int) -> int:
    """Remove the root of a 4-ary min-heap; returns the new size."""
    size -= 1
    if size == 0:
        return 0
    key = keys[size]
    val = vals[size]
    i = 0
    while True:
        first = 4 * i + 1
        if first >= size:
            break
        child = first
        ck = keys[first]
        for c in range(first + 1, min(first + 4, size)):
            if keys[c] < ck:
                ck = keys[c]
                child = c
        if key <= ck:
            break
        keys[i] = ck
        vals[i] = vals[child]
        i = child
    keys[i] = key
    vals[i] = val
    return size


@numba.njit(inline="always", **_NOPYTHON)  # type: ignore[misc]
def _source_offset(pos_se: NDArray[np.int64], pos_off: NDArray[np.int64], source: int, se: int) -> int:
    """Offset of an interior ``source`` on super-edge ``se`` (-1 when the source does not lie on it)."""
    for j in range(2):
        if pos_se[source, j] == se:
            return int(pos_off[source, j])
    return -1


@numba.njit(inline="always", **_NOPYTHON)  # type: ignore[misc]
def _target_need(
    kept_of: NDArray[np.int64],
    se_tail: NDArray[np.int64],
    pos_se: NDArray[np.int64],
    pos_off: NDArray[np.int64],
    source: int,
    targets: NDArray[np.int64],
    nk: int,
) -> tuple[NDArray[np.bool_], int]:
    """The kept nodes a search must settle before every target is known, and how many there are: a kept
    target itself, and for an interior target the tail of each super-edge it lies on (unless the source
    reaches it directly along that super-edge)."""
    need = np.zeros(nk, dtype=np.bool_)
    sk = kept_of[source]
    remaining = 0
    for t in targets:
        if t == source:
            continue
        k = kept_of[t]
        if k >= 0:
            if not need[k]:
                need[k] = True
                remaining += 1
            continue
        for j in range(2):
            s = pos_se[t, j]
            if s < 0:
                continue
            if sk < 0:
                os = _source_offset(pos_se, pos_off, source, s)
                if os >= 0 and os < pos_off[t, j]:
                    continue  # reached directly from the source along this super-edge
            k = se_tail[s]
            if not need[k]:
                need[k] = True
                remaining += 1
    return need, remaining


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def _unfold_chain(
    k: int,
    se_tail: NDArray[np.int64],
    se_ptr: NDArray[np.int64],
    se_edges: NDArray[np.int64],
    se_node: NDArray[np.int64],
    tent: NDArray[np.float64],
    acc_t: NDArray[np.float64],
    pse: NDArray[np.int64],
    pstart: NDArray[np.int64],
    unfolded: NDArray[np.bool_],
    cost: NDArray[np.float64],
    aux: NDArray[np.float64],
    dist: NDArray[np.float64],
    pred: NDArray[np.int64],
    acc: NDArray[np.float64],
) -> None:
    """Write dist/pred/acc of the interior nodes on the tree path to settled kept node ``k``."""
    while not unfolded[k]:
        unfolded[k] = True
        s = pse[k]
        if s < 0:
            return
        start = pstart[k]
        t = se_tail[s]
        x = tent[t] if start == 0 else 0.0
        a = acc_t[t] if start == 0 else 0.0
        for p in range(se_ptr[s] + start, se_ptr[s + 1] - 1):
            e = se_edges[p]
            x += cost[e]
            a += aux[e]
            v = se_node[p]
            dist[v] = x
            pred[v] = e
            acc[v] = a
        if start != 0:
            return
        k = t


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def dijkstra_contracted(
    k_indptr: NDArray[np.int64],
    se_head: NDArray[np.int64],
    se_tail: NDArray[np.int64],
    se_rev: NDArray[np.int64],
    se_ptr: NDArray[np.int64],
    se_edges: NDArray[np.int64],
    se_node: NDArray[np.int64],
    kept: NDArray[np.int64],
    kept_of: NDArray[np.int64],
    dead_end: NDArray[np.bool_],
    pos_se: NDArray[np.int64],
    pos_off: NDArray[np.int64],
    cost: NDArray[np.float64],
    aux: NDArray[np.float64],
    source: int,
    limit: float,
    targets: NDArray[np.int64],
    queries: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """``dijkstra`` on a graph whose chains of degree-2 nodes are contracted (``services.contraction``).

    Kept node ``k`` (original node ``kept[k]``) leaves along super-edges ``k_indptr[k]:k_indptr[k+1]``;
    super-edge ``s`` runs ``se_tail[s] -> se_head[s]`` (kept indices) over the original edges
    ``se_edges[se_ptr[s]:se_ptr[s+1]]``, the node after each being ``se_node``; ``se_rev[s]`` is the
    super-edge over the same interior nodes the other way (-1 if none). An interior node lies on
    ``pos_se[v, j]`` (j = 0, 1; -1 unused, ascending) with ``pos_off[v, j]`` original edges before it.
    A kept node with ``dead_end`` set has one neighbour only: it is settled when reached and never queued.
    ``cost`` and ``aux`` are per original edge; a super-edge's cost is folded edge by edge from the tail's
    distance, so distances are bit-identical to ``dijkstra``'s.

    Same arguments and results as ``dijkstra``, except that ``dist``, ``pred_edge`` and the ``aux`` sums are
    written only for the source, the settled kept nodes, the nodes of ``queries`` and the nodes on their
    tree paths (``walk_edges`` works from each of these); other nodes read as not settled. ``targets``
    stops the search as in ``dijkstra`` (an interior target waits for both ends of its chain); after such a
    stop, a query that is not a target may read as not settled where ``dijkstra`` would have settled it,
    but is never given a wrong value.
    """
    n = kept_of.shape[0]
    nk = kept.shape[0]
    ns = se_head.shape[0]
    tent = np.full(nk, np.inf)
    acc_t = np.zeros(nk)
    pse = np.full(nk, -1, dtype=np.int64)
    pstart = np.zeros(nk, dtype=np.int64)
    done = np.zeros(nk, dtype=np.bool_)
    sk = kept_of[source]
    stop_early = targets.shape[0] > 0
    need, remaining = _target_need(kept_of, se_tail, pos_se, pos_off, source, targets, nk)
    keys = np.empty(ns + 3)
    vals = np.empty(ns + 3, dtype=np.int64)
    size = 0
    complete = not (stop_early and remaining == 0)  # False: unsettled kept nodes may still be near
    if complete:
        if sk >= 0:
            tent[sk] = 0.0
            size = _heap4_push(keys, vals, size, 0.0, sk)
        else:
            for j in range(2):
                s = pos_se[source, j]
                if s < 0:
                    continue
                os = pos_off[source, j]
                h = se_head[s]
                nd = 0.0
                a = 0.0
                for p in range(se_ptr[s] + os, se_ptr[s + 1]):
                    nd += cost[se_edges[p]]
                    a += aux[se_edges[p]]
                if nd < tent[h] and nd <= limit:
                    tent[h] = nd
                    acc_t[h] = a
                    pse[h] = s
                    pstart[h] = os
                    size = _heap4_push(keys, vals, size, nd, h)
    while size > 0:
        d = keys[0]
        k = vals[0]
        size = _heap4_pop(keys, vals, size)
        if done[k]:
            continue
        if d > limit:
            break
        done[k] = True
        if need[k]:
            remaining -= 1
            if remaining == 0:
                complete = False
                break
        for s in range(k_indptr[k], k_indptr[k + 1]):
            h = se_head[s]
            if done[h]:
                continue
            th = tent[h]
            nd = d
            ok = True
            for p in range(se_ptr[s], se_ptr[s + 1]):
                nd += cost[se_edges[p]]
                if nd >= th or nd > limit:  # partial sums never decrease: no improvement
                    ok = False
                    break
            if ok:
                a = acc_t[k]
                for p in range(se_ptr[s], se_ptr[s + 1]):
                    a += aux[se_edges[p]]
                tent[h] = nd
                acc_t[h] = a
                pse[h] = s
                pstart[h] = 0
                if not dead_end[h]:
                    size = _heap4_push(keys, vals, size, nd, h)
                    continue
                done[h] = True  # a dead end has no other way in: settled now, and nothing to relax
                if need[h]:
                    remaining -= 1
                    if remaining == 0:
                        complete = False
                        size = 0
                        break
    dist = np.full(n, np.inf)
    pred = np.full(n, -1, dtype=np.int64)
    acc = np.full(n, np.nan)
    for k in range(nk):
        if done[k]:
            v = kept[k]
            dist[v] = tent[k]
            acc[v] = acc_t[k]
            if pse[k] >= 0:
                pred[v] = se_edges[se_ptr[pse[k] + 1] - 1]
    if limit >= 0.0:
        dist[source] = 0.0
        acc[source] = 0.0
        pred[source] = -1
    unfolded = np.zeros(nk, dtype=np.bool_)
    for q in queries:
        if q == source:
            continue
        k = kept_of[q]
        if k >= 0:
            if done[k]:
                _unfold_chain(
                    k,
                    se_tail,
                    se_ptr,
                    se_edges,
                    se_node,
                    tent,
                    acc_t,
                    pse,
                    pstart,
                    unfolded,
                    cost,
                    aux,
                    dist,
                    pred,
                    acc,
                )
            continue
        # interior node: the best of reaching it along each super-edge it lies on (ties: lower super-edge)
        best = np.inf
        bj = -1
        bstart = 0
        unknown = False
        for j in range(2):
            s = pos_se[q, j]
            if s < 0:
                continue
            off = pos_off[q, j]
            os = _source_offset(pos_se, pos_off, source, s) if sk < 0 else -1
            if os >= 0 and os < off:
                start = os
                x = 0.0
            else:
                t = se_tail[s]
                if not done[t]:
                    unknown = unknown or not complete
                    continue
                if se_rev[s] >= 0 and pse[t] == se_rev[s]:
                    continue  # the tail is reached through this very chain
                start = 0
                x = tent[t]
            for p in range(se_ptr[s] + start, se_ptr[s] + off):
                x += cost[se_edges[p]]
            if x < best:
                best = x
                bj = j
                bstart = start
        if bj < 0 or best > limit or unknown:
            continue
        s = pos_se[q, bj]
        t = se_tail[s]
        x = tent[t] if bstart == 0 else 0.0
        a = acc_t[t] if bstart == 0 else 0.0
        for p in range(se_ptr[s] + bstart, se_ptr[s] + pos_off[q, bj]):
            e = se_edges[p]
            x += cost[e]
            a += aux[e]
            v = se_node[p]
            dist[v] = x
            pred[v] = e
            acc[v] = a
        if bstart == 0:
            _unfold_chain(
                t,
                se_tail,
                se_ptr,
                se_edges,
                se_node,
                tent,
                acc_t,
                pse,
                pstart,
                unfolded,
                cost,
                aux,
                dist,
                pred,
                acc,
            )
    return dist, pred, acc


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def tree_search(
    k_indptr: NDArray[np.int64],
    se_head: NDArray[np.int64],
    se_tail: NDArray[np.int64],
    se_rev: NDArray[np.int64],
    se_ptr: NDArray[np.int64],
    se_edges: NDArray[np.int64],
    se_node: NDArray[np.int64],
    kept: NDArray[np.int64],
    kept_of: NDArray[np.int64],
    dead_end: NDArray[np.bool_],
    pos_se: NDArray[np.int64],
    pos_off: NDArray[np.int64],
    cost_se: NDArray[np.float64],
    source: int,
    targets: NDArray[np.int64],
    pred: NDArray[np.int64],
) -> None:
    """The predecessor edges of ``dijkstra_contracted`` with no limit, no ``aux`` and ``queries = targets``
    (the searches of Algorithm 1), written into ``pred`` (all -1 on entry).

    ``cost_se[p]`` is the cost of original edge ``se_edges[p]``: the costs in super-edge order, read
    contiguously. Every distance is folded from the same values in the same order as in
    ``dijkstra_contracted`` and the heap sees the same keys in the same order, so the tree is the same;
    what is left out is only what Algorithm 1 never reads (distances, ``aux`` sums).
    """
    nk = kept.shape[0]
    ns = se_head.shape[0]
    tent = np.full(nk, np.inf)
    pse = np.full(nk, -1, dtype=np.int64)
    pstart = np.zeros(nk, dtype=np.int64)
    done = np.zeros(nk, dtype=np.bool_)
    sk = kept_of[source]
    stop_early = targets.shape[0] > 0
    need, remaining = _target_need(kept_of, se_tail, pos_se, pos_off, source, targets, nk)
    keys = np.empty(ns + 3)
    vals = np.empty(ns + 3, dtype=np.int64)
    size = 0
    complete = not (stop_early and remaining == 0)  # False: unsettled kept nodes may still be near
    if complete:
        if sk >= 0:
            tent[sk] = 0.0
            size = _heap4_push(keys, vals, size, 0.0, sk)
        else:
            for j in range(2):
                s = pos_se[source, j]
                if s < 0:
                    continue
                os = pos_off[source, j]
                h = se_head[s]
                nd = 0.0
                for p in range(se_ptr[s] + os, se_ptr[s + 1]):
                    nd += cost_se[p]
                if nd < tent[h]:
                    tent[h] = nd
                    pse[h] = s
                    pstart[h] = os
                    size = _heap4_push(keys, vals, size, nd, h)
    while size > 0:
        d = keys[0]
        k = vals[0]
        size = _heap4_pop(keys, vals, size)
        if done[k]:
            continue
        done[k] = True
        if need[k]:
            remaining -= 1
            if remaining == 0:
                complete = False
                break
        for s in range(k_indptr[k], k_indptr[k + 1]):
            h = se_head[s]
            if done[h]:
                continue
            th = tent[h]
            nd = d
            ok = True
            for p in range(se_ptr[s], se_ptr[s + 1]):
                nd += cost_se[p]
                if nd >= th:  # partial sums never decrease: no improvement
                    ok = False
                    break
            if ok:
                tent[h] = nd
                pse[h] = s
                pstart[h] = 0
                if not dead_end[h]:
                    size = _heap4_push(keys, vals, size, nd, h)
                    continue
                done[h] = True  # a dead end has no other way in: settled now, and nothing to relax
                if need[h]:
                    remaining -= 1
                    if remaining == 0:
                        complete = False
                        size = 0
                        break
    for k in range(nk):
        if done[k] and pse[k] >= 0:
            pred[kept[k]] = se_edges[se_ptr[pse[k] + 1] - 1]
    pred[source] = -1
    unfolded = np.zeros(nk, dtype=np.bool_)
    for q in targets:
        if q == source:
            continue
        k = kept_of[q]
        if k >= 0:
            if done[k]:
                _unfold_pred(k, se_tail, se_ptr, se_edges, se_node, pse, pstart, unfolded, pred)
            continue
        # interior node: the best of reaching it along each super-edge it lies on (ties: lower super-edge)
        best = np.inf
        bj = -1
        bstart = 0
        unknown = False
        for j in range(2):
            s = pos_se[q, j]
            if s < 0:
                continue
            off = pos_off[q, j]
            os = _source_offset(pos_se, pos_off, source, s) if sk < 0 else -1
            if os >= 0 and os < off:
                start = os
                x = 0.0
            else:
                t = se_tail[s]
                if not done[t]:
                    unknown = unknown or not complete
                    continue
                if se_rev[s] >= 0 and pse[t] == se_rev[s]:
                    continue  # the tail is reached through this very chain
                start = 0
                x = tent[t]
            for p in range(se_ptr[s] + start, se_ptr[s] + off):
                x += cost_se[p]
            if x < best:
                best = x
                bj = j
                bstart = start
        if bj < 0 or unknown:
            continue
        s = pos_se[q, bj]
        for p in range(se_ptr[s] + bstart, se_ptr[s] + pos_off[q, bj]):
            pred[se_node[p]] = se_edges[p]
        if bstart == 0:
            _unfold_pred(se_tail[s], se_tail, se_ptr, se_edges, se_node, pse, pstart, unfolded, pred)


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def _unfold_pred(
    k: int,
    se_tail: NDArray[np.int64],
    se_ptr: NDArray[np.int64],
    se_edges: NDArray[np.int64],
    se_node: NDArray[np.int64],
    pse: NDArray[np.int64],
    pstart: NDArray[np.int64],
    unfolded: NDArray[np.bool_],
    pred: NDArray[np.int64],
) -> None:
    """``_unfold_chain`` for the predecessor edges only."""
    while not unfolded[k]:
        unfolded[k] = True
        s = pse[k]
        if s < 0:
            return
        start = pstart[k]
        for p in range(se_ptr[s] + start, se_ptr[s + 1] - 1):
            pred[se_node[p]] = se_edges[p]
        if start != 0:
            return
        k = se_tail[s]


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def walk_edges(pred_edge: NDArray[np.int64], tail: NDArray[np.int32], target: int) -> NDArray[np.int64]:
    """Edges of the tree path ending at ``target``, in travel order (empty at the root)."""
    count = 0
    v = target
    while pred_edge[v] >= 0:
        count += 1
        v = tail[pred_edge[v]]
    out = np.empty(count, dtype=np.int64)
    v = target
    i = count - 1
    while pred_edge[v] >= 0:
        e = pred_edge[v]
        out[i] = e
        v = tail[e]
        i -= 1
    return out


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def walk_succ(succ_edge: NDArray[np.int64], head: NDArray[np.int32], start: int) -> NDArray[np.int64]:
    """Edges from ``start`` to the root of a reverse (in-)tree, following ``succ_edge``, in travel order."""
    count = 0
    v = start
    while succ_edge[v] >= 0:
        count += 1
        v = head[succ_edge[v]]
    out = np.empty(count, dtype=np.int64)
    v = start
    for i in range(count):
        out[i] = succ_edge[v]
        v = head[out[i]]
    return out


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def distinct_cells(
    edges: NDArray[np.int64], ec_ptr: NDArray[np.int64], ec_cell: NDArray[np.int32], n_cells: int
) -> NDArray[np.int64]:
    """The distinct cells the edges cross, in order of first crossing (a path's G-route)."""
    seen = np.zeros(n_cells, dtype=np.bool_)
    out = np.empty(n_cells, dtype=np.int64)
    n = 0
    for e in edges:
        for j in range(ec_ptr[e], ec_ptr[e + 1]):
            c = ec_cell[j]
            if not seen[c]:
                seen[c] = True
                out[n] = c
                n += 1
    return out[:n]


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def crossings(
    edges: NDArray[np.int64],
    depart_s: float,
    edge_time: NDArray[np.float64],
    ec_ptr: NDArray[np.int64],
    ec_cell: NDArray[np.int32],
    ec_frac: NDArray[np.float64],
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Every cell crossing of a path and its time, as ``sensing.timed_cells`` computes them: edge ``i``
    starts at ``depart_s`` plus the running sum of the earlier edges' times, a crossing at ``start +
    fraction x edge time``."""
    total = 0
    for e in edges:
        total += ec_ptr[e + 1] - ec_ptr[e]
    cells = np.empty(total, dtype=np.int64)
    entry = np.empty(total)
    n = 0
    run = 0.0
    for i in range(edges.shape[0]):
        e = edges[i]
        te = edge_time[e]
        start = depart_s + run
        for j in range(ec_ptr[e], ec_ptr[e + 1]):
            cells[n] = ec_cell[j]
            entry[n] = start + ec_frac[j] * te
            n += 1
        run = te if i == 0 else run + te
    return cells, entry


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def first_pairs(
    cells: NDArray[np.int64], entry: NDArray[np.float64], shift_s: float, interval_s: float, n_cells: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The distinct (interval, cell) pairs of timed crossings, in order of first entry; the interval of a
    time is ``floor((t + shift_s) / interval_s)``."""
    n = cells.shape[0]
    ks = np.empty(n, dtype=np.int64)
    k_min = 0
    k_max = 0
    for i in range(n):
        ks[i] = np.int64(np.floor((entry[i] + shift_s) / interval_s))
        if i == 0 or ks[i] < k_min:
            k_min = ks[i]
        if i == 0 or ks[i] > k_max:
            k_max = ks[i]
    seen = np.zeros((k_max - k_min + 1 if n else 0, n_cells), dtype=np.bool_)
    out_k = np.empty(n, dtype=np.int64)
    out_c = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if not seen[ks[i] - k_min, cells[i]]:
            seen[ks[i] - k_min, cells[i]] = True
            out_k[m] = ks[i]
            out_c[m] = cells[i]
            m += 1
    return out_k[:m], out_c[:m]


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def eval_path(
    edges: NDArray[np.int64],
    depart_s: float,
    edge_time: NDArray[np.float64],
    ec_ptr: NDArray[np.int64],
    ec_cell: NDArray[np.int32],
    ec_frac: NDArray[np.float64],
    interval_shift_s: float,
    interval_s: float,
    k0: int,
    gain: NDArray[np.float64],
    gain_q: NDArray[np.int64],
    stamp: NDArray[np.int64],
    stamp_id: int,
) -> tuple[float, int, float, int, int]:
    """Exact marginal gain of one path (METHOD section 3).

    ``gain[slot, cell]`` is the term for interval ``k0 + slot`` (0 where the taxi is already counted),
    ``gain_q`` its integer quantization. A (slot, cell) pair counts at its first entry only; ``stamp``
    (same shape, values < ``stamp_id`` on entry) records pairs seen on this path. Returns (gain, integer
    gain, travel time, number of counted terms, largest slot reached; -1 slot overflow is reported as a
    slot >= gain.shape[0]).
    """
    n_slots = gain.shape[0]
    t = depart_s
    g = 0.0
    gq = 0
    terms = 0
    max_slot = 0
    for i in range(edges.shape[0]):
        e = edges[i]
        te = edge_time[e]
        for j in range(ec_ptr[e], ec_ptr[e + 1]):
            entry = t + ec_frac[j] * te
            slot = int(np.floor((entry + interval_shift_s) / interval_s)) - k0
            if slot > max_slot:
                max_slot = slot
            if slot >= n_slots:
                continue
            c = ec_cell[j]
            if stamp[slot, c] == stamp_id:
                continue
            stamp[slot, c] = stamp_id
            if gain[slot, c] > 0.0:
                g += gain[slot, c]
                gq += gain_q[slot, c]
                terms += 1
        t += te
    return g, gq, t - depart_s, terms, max_slot


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def eval_pairs(
    pair_table: NDArray[np.int64],
    pair_leg: NDArray[np.int64],
    pair_depart: NDArray[np.float64],
    leg_ptr: NDArray[np.int64],
    leg_edges: NDArray[np.int64],
    edge_time: NDArray[np.float64],
    ec_ptr: NDArray[np.int64],
    ec_cell: NDArray[np.int32],
    ec_frac: NDArray[np.float64],
    interval_shift_s: float,
    interval_s: float,
    k0: int,
    gains: NDArray[np.float64],
    gains_q: NDArray[np.int64],
    stamp: NDArray[np.int64],
    stamp_base: int,
) -> tuple[NDArray[np.float64], NDArray[np.int64], int]:
    """``eval_path`` for many (gain table, leg, departure) triples: leg ``i`` is
    ``leg_edges[leg_ptr[i]:leg_ptr[i+1]]``, table ``j`` is ``gains[j]``. Returns gains, integer gains and the
    largest slot reached."""
    k = pair_table.shape[0]
    out_g = np.zeros(k)
    out_q = np.zeros(k, dtype=np.int64)
    max_slot = 0
    for i in range(k):
        leg = pair_leg[i]
        tab = pair_table[i]
        g, gq, _t, _terms, ms = eval_path(
            leg_edges[leg_ptr[leg] : leg_ptr[leg + 1]],
            pair_depart[i],
            edge_time,
            ec_ptr,
            ec_cell,
            ec_frac,
            interval_shift_s,
            interval_s,
            k0,
            gains[tab],
            gains_q[tab],
            stamp,
            stamp_base + i,
        )
        out_g[i] = g
        out_q[i] = gq
        if ms > max_slot:
            max_slot = ms
    return out_g, out_q, max_slot


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def eval_targets(
    pred_edge: NDArray[np.int64],
    tail: NDArray[np.int32],
    targets: NDArray[np.int64],
    depart_s: float,
    edge_time: NDArray[np.float64],
    edge_len: NDArray[np.float64],
    ec_ptr: NDArray[np.int64],
    ec_cell: NDArray[np.int32],
    ec_frac: NDArray[np.float64],
    interval_shift_s: float,
    interval_s: float,
    k0: int,
    gain: NDArray[np.float64],
    gain_q: NDArray[np.int64],
    stamp: NDArray[np.int64],
    stamp_base: int,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], int]:
    """``eval_path`` for the tree path to every target; unreachable targets get NaN time.

    Returns gains, integer gains, travel times, lengths and the largest slot reached.
    """
    k = targets.shape[0]
    out_g = np.zeros(k)
    out_q = np.zeros(k, dtype=np.int64)
    out_t = np.full(k, np.nan)
    out_l = np.full(k, np.nan)
    max_slot = 0
    for i in range(k):
        tgt = targets[i]
        edges = walk_edges(pred_edge, tail, tgt)
        g, gq, tt, _terms, ms = eval_path(
            edges,
            depart_s,
            edge_time,
            ec_ptr,
            ec_cell,
            ec_frac,
            interval_shift_s,
            interval_s,
            k0,
            gain,
            gain_q,
            stamp,
            stamp_base + i,
        )
        length = 0.0
        for e in edges:
            length += edge_len[e]
        out_g[i] = g
        out_q[i] = gq
        out_t[i] = tt
        out_l[i] = length
        if ms > max_slot:
            max_slot = ms
    return out_g, out_q, out_t, out_l, max_slot


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def eval_tree(
    pred_edge: NDArray[np.int64],
    tail: NDArray[np.int32],
    source: int,
    targets: NDArray[np.int64],
    depart_s: float,
    edge_time: NDArray[np.float64],
    edge_len: NDArray[np.float64],
    ec_ptr: NDArray[np.int64],
    ec_cell: NDArray[np.int32],
    ec_frac: NDArray[np.float64],
    interval_shift_s: float,
    interval_s: float,
    k0: int,
    gain: NDArray[np.float64],
    gain_q: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], int]:
    """``eval_targets`` computed once per tree edge instead of once per path edge.

    The tree paths to the targets share their prefixes; a depth-first walk over the union of those paths
    carries each path's running state (time, gain, integer gain, length, largest slot, and the set of
    (slot, cell) pairs seen so far, undone on the way back up) from a node to its children. Every quantity
    is accumulated edge by edge from the source in travel order, exactly as ``eval_path`` does along one
    path, so the results are bit-identical to ``eval_targets`` (unreachable targets included: they read
    as an empty path, time 0, which ``eval_targets`` also returns for them).
    """
    n = pred_edge.shape[0]
    k = targets.shape[0]
    n_slots = gain.shape[0]
    n_cells = gain.shape[1]
    # the union of the targets' tree paths, each member's children, and where each target's result goes
    in_union = np.zeros(n, dtype=np.bool_)
    first_of = np.full(n, -1, dtype=np.int64)  # the first index in ``targets`` of a node
    members = np.empty(n, dtype=np.int64)
    n_mem = 0
    for i in range(k):
        v = targets[i]
        if first_of[v] < 0:
            first_of[v] = i
        while pred_edge[v] >= 0 and not in_union[v]:
            in_union[v] = True
            members[n_mem] = v
            n_mem += 1
            v = tail[pred_edge[v]]
    kid_ptr = np.zeros(n + 1, dtype=np.int64)
    for q in range(n_mem):
        kid_ptr[tail[pred_edge[members[q]]] + 1] += 1
    for v in range(n):
        kid_ptr[v + 1] += kid_ptr[v]
    fill = kid_ptr[:-1].copy()
    kids = np.empty(max(n_mem, 1), dtype=np.int64)
    for q in range(n_mem):
        p = tail[pred_edge[members[q]]]
        kids[fill[p]] = members[q]
        fill[p] += 1
    out_g = np.zeros(k)
    out_q = np.zeros(k, dtype=np.int64)
    out_t = np.zeros(k)
    out_l = np.zeros(k)
    out_ms = np.zeros(k, dtype=np.int64)
    # depth-first, the running state of the current path kept per depth
    seen = np.zeros((n_slots, n_cells), dtype=np.bool_)
    log_s = np.empty(n_slots * n_cells + 1, dtype=np.int64)
    log_c = np.empty(n_slots * n_cells + 1, dtype=np.int64)
    n_log = 0
    st_node = np.empty(n_mem + 1, dtype=np.int64)
    st_next = np.empty(n_mem + 1, dtype=np.int64)
    st_log = np.empty(n_mem + 1, dtype=np.int64)
    st_t = np.empty(n_mem + 1)
    st_g = np.empty(n_mem + 1)
    st_q = np.empty(n_mem + 1, dtype=np.int64)
    st_l = np.empty(n_mem + 1)
    st_ms = np.empty(n_mem + 1, dtype=np.int64)
    st_node[0] = source
    st_next[0] = kid_ptr[source]
    st_log[0] = 0
    st_t[0] = depart_s
    st_g[0] = 0.0
    st_q[0] = 0
    st_l[0] = 0.0
    st_ms[0] = 0
    depth = 0
    while depth >= 0:
        v = st_node[depth]
        it = st_next[depth]
        if it < kid_ptr[v + 1]:
            st_next[depth] = it + 1
            w = kids[it]
            e = pred_edge[w]
            t = st_t[depth]
            g = st_g[depth]
            gq = st_q[depth]
            ms = st_ms[depth]
            te = edge_time[e]
            start = n_log
            for j in range(ec_ptr[e], ec_ptr[e + 1]):
                entry = t + ec_frac[j] * te
                slot = int(np.floor((entry + interval_shift_s) / interval_s)) - k0
                if slot > ms:
                    ms = slot
                if slot >= n_slots:
                    continue
                c = ec_cell[j]
                if seen[slot, c]:
                    continue
                seen[slot, c] = True
                log_s[n_log] = slot
                log_c[n_log] = c
                n_log += 1
                if gain[slot, c] > 0.0:
                    g += gain[slot, c]
                    gq += gain_q[slot, c]
            length = st_l[depth] + edge_len[e]
            depth += 1
            st_node[depth] = w
            st_next[depth] = kid_ptr[w]
            st_log[depth] = start
            st_t[depth] = t + te
            st_g[depth] = g
            st_q[depth] = gq
            st_l[depth] = length
            st_ms[depth] = ms
            i = first_of[w]
            if i >= 0:
                out_g[i] = g
                out_q[i] = gq
                out_t[i] = (t + te) - depart_s
                out_l[i] = length
                out_ms[i] = ms
        else:
            for q in range(st_log[depth], n_log):
                seen[log_s[q], log_c[q]] = False
            n_log = st_log[depth]
            depth -= 1
    max_slot = 0
    for i in range(k):
        f = first_of[targets[i]]
        if f != i:  # a repeated target: the result of its first occurrence
            out_g[i] = out_g[f]
            out_q[i] = out_q[f]
            out_t[i] = out_t[f]
            out_l[i] = out_l[f]
            out_ms[i] = out_ms[f]
        if out_ms[i] > max_slot:
            max_slot = out_ms[i]
    return out_g, out_q, out_t, out_l, max_slot


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def entered_utility(
    ec_ptr: NDArray[np.int64], ec_cell: NDArray[np.int32], cell_value: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per edge, the sum of ``cell_value`` over the cells the edge *enters* (all but its first cell)."""
    m = ec_ptr.shape[0] - 1
    out = np.zeros(m)
    for e in range(m):
        s = 0.0
        for j in range(ec_ptr[e] + 1, ec_ptr[e + 1]):
            s += cell_value[ec_cell[j]]
        out[e] = s
    return out


@numba.njit(**_NOPYTHON)  # type: ignore[misc]
def plan_kappas(
    c_indptr: NDArray[np.int64],
    c_se_head: NDArray[np.int64],
    c_se_tail: NDArray[np.int64],
    c_se_rev: NDArray[np.int64],
    c_se_ptr: NDArray[np.int64],
    c_se_edges: NDArray[np.int64],
    c_se_node: NDArray[np.int64],
    c_kept: NDArray[np.int64],
    c_kept_of: NDArray[np.int64],
    c_dead_end: NDArray[np.bool_],
    c_pos_se: NDArray[np.int64],
    c_pos_off: NDArray[np.int64],
    tail: NDArray[np.int32],
    edge_time: NDArray[np.float64],
    edge_len: NDArray[np.float64],
    ec_ptr: NDArray[np.int64],
    ec_cell: NDArray[np.int32],
    ec_frac: NDArray[np.float64],
    kappas: NDArray[np.float64],
    source: int,
    targets: NDArray[np.int64],
    depart_s: float,
    interval_shift_s: float,
    interval_s: float,
    k0: int,
    gain: NDArray[np.float64],
    gain_q: NDArray[np.int64],
    has_fastest: bool,
    fastest: NDArray[np.int64],
    fastest_head: NDArray[np.int64],
) -> tuple[
    NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], int
]:
    """Algorithm 1 for one taxi and every target in one call, on the contracted graph.

    Exactly what ``routing.plan_routes`` does step by step: edge costs ``t_e (1 - kappa u_e / max u)`` per
    kappa (kappas > 0 skipped when no edge enters a cell of positive gain), one contracted search each,
    every target's tree path evaluated (``eval_tree``), and per target the kappa with the largest phi kept
    (ties: the earlier kappa). Returns the chosen kappa index per target (-1 unreachable), gain, time and
    length of the chosen routes, the predecessor-edge arrays (one row per kappa; rows of skipped kappas
    are -1) and the largest interval slot reached. With ``has_fastest`` the kappa = 0 tree is not grown but
    given: the edges ``fastest`` of its path to the (single) target, entering ``fastest_head``.
    """
    m = edge_time.shape[0]
    n = c_kept_of.shape[0]
    k = targets.shape[0]
    u = entered_utility(ec_ptr, ec_cell, gain[0])
    umax = 0.0
    for e in range(m):
        if u[e] > umax:
            umax = u[e]
    best_phi = np.full(k, -np.inf)
    out_i = np.full(k, -1, dtype=np.int64)
    out_g = np.zeros(k)
    out_t = np.full(k, np.nan)
    out_l = np.zeros(k)
    preds = np.full((kappas.shape[0], n), -1, dtype=np.int64)
    cost_se = np.empty(m)  # edge costs in super-edge order (what tree_search reads)
    max_slot = 0
    for ki in range(kappas.shape[0]):
        kappa = kappas[ki]
        pred = preds[ki]
        if kappa == 0.0 and has_fastest:
            for j in range(fastest.shape[0]):
                pred[fastest_head[j]] = fastest[j]
        else:
            if kappa == 0.0:
                for p in range(m):
                    cost_se[p] = edge_time[c_se_edges[p]]
            elif umax > 0.0:
                for p in range(m):
                    e = c_se_edges[p]
                    cost_se[p] = edge_time[e] * (1.0 - kappa * (u[e] / umax))
            else:
                continue
            tree_search(
                c_indptr,
                c_se_head,
                c_se_tail,
                c_se_rev,
                c_se_ptr,
                c_se_edges,
                c_se_node,
                c_kept,
                c_kept_of,
                c_dead_end,
                c_pos_se,
                c_pos_off,
                cost_se,
                source,
                targets,
                pred,
            )
        g, _gq, t, length, ms = eval_tree(
            pred,
            tail,
            source,
            targets,
            depart_s,
            edge_time,
            edge_len,
            ec_ptr,
            ec_cell,
            ec_frac,
            interval_shift_s,
            interval_s,
            k0,
            gain,
            gain_q,
        )
        if ms > max_slot:
            max_slot = ms
        for i in range(k):
            tgt = targets[i]
            if np.isnan(t[i]) or not (pred[tgt] >= 0 or tgt == source):
                continue
            phi = g[i] / t[i] if t[i] > 0 else 0.0
            if phi > best_phi[i]:
                best_phi[i] = phi
                out_i[i] = ki
                out_g[i] = g[i]
                out_t[i] = t[i]
                out_l[i] = length[i]
    return out_i, out_g, out_t, out_l, preds, max_slot
