"""Sensing gains of paths: the marginal terms of Eq. (3), exact path evaluation, timed G-routes.

A :class:`Gains` table holds, for the intervals ``k0 .. k0+S-1`` of an epoch (rows, "slots") and every grid
cell, the term ``mu_t s_g ((Lambda + 1)**rho - Lambda**rho)`` that a first visit adds, and a fixed-point
copy of it: ``term_q = ceil(term / unit)`` for a positive term, 0 for a zero one. The fixed-point sums are
exact and do not depend on the order of addition, which the exact assignments of Steps 1-3 need
(``services.matching.assignment``); a positive term never rounds to 0, so a path's fixed-point gain is
positive exactly when its gain is. A taxi already counted in a (slot, cell) gains nothing there: the kernels
take a *zero mask* per taxi instead of a copy of the table per taxi.

Path evaluation (docs/METHOD.md section 3): edge ``i`` of a path starts at the departure time plus the
running sum of the earlier edges' times; a crossing at ``start + fraction x edge time`` falls in the
interval ``floor((t + shift) / interval)``; a (slot, cell) pair counts at its first entry only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import chain
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.model import IntervalKey, TaxiId
from services.network.graph import Edges, road_graph
from services.sensing.sensing import theta_gain

if TYPE_CHECKING:
    from services.city import City

__all__ = [
    "Gains",
    "gain_table",
    "Counted",
    "counted_csr",
    "counted_rows",
    "mark",
    "eval_path",
    "eval_tree",
    "TreeScratch",
    "TreeOut",
    "tree_scratch",
    "eval_pairs",
    "pair_gains_q",
    "distinct_cells",
    "path_facts",
    "timed_pairs",
    "fixed_point_unit",
]

TERM_BITS = 40
"""Default fixed-point resolution: the largest term is 2**40 units."""


class Gains(NamedTuple):
    """The marginal terms of an epoch's intervals ``k0 .. k0 + S - 1`` (rows) for every cell (columns)."""

    term: NDArray[np.float64]  # (S, C)
    term_q: NDArray[np.int64]  # (S, C) ceil(term / unit), 0 where term is 0
    unit: float
    shift_s: float  # slot of time t: floor((t + shift_s) / interval_s) - k0
    interval_s: float
    k0: int

    @property
    def n_slots(self) -> int:
        return int(self.term.shape[0])


def gain_table(
    city: City,
    counts: Mapping[IntervalKey, NDArray[np.int64]],
    k0: int,
    n_slots: int,
    depart_s: float,
    *,
    extra_counts: NDArray[np.int64] | None = None,
    unit: float | None = None,
) -> Gains:
    """The terms for intervals ``k0..k0+n_slots-1`` given ``counts`` (plus ``extra_counts[slot, cell]``
    planned visits: counts are whole numbers, so Lambda + n is exact), with the fixed-point ``unit``
    (default: the largest term / 2**40)."""
    rho = city.params.rho
    n_cells = city.grid.n_cells
    term = np.zeros((n_slots, n_cells))
    for s in range(n_slots):
        k = IntervalKey(k0 + s)
        lam = counts.get(k)
        lam_f = np.zeros(n_cells) if lam is None else lam.astype(np.float64)
        if extra_counts is not None:
            lam_f = lam_f + extra_counts[s]
        term[s] = city.mu(k) * city.cell_weight * theta_gain(lam_f, 1.0, rho)
    top = float(term.max(initial=0.0))
    if unit is None:
        unit = top / 2.0**TERM_BITS if top > 0 else 1.0
    term_q = np.where(term > 0, np.ceil(term / unit), 0).astype(np.int64)
    return Gains(
        term, term_q, float(unit), city.horizon.shift_s(depart_s), float(city.horizon.interval_s), k0
    )


class Counted(NamedTuple):
    """Several taxis' counted (interval, cell) pairs as CSR: taxi ``i`` is counted in
    ``(k0 + slot[ptr[i]:ptr[i+1]], cell[ptr[i]:ptr[i+1]])`` (pairs before ``k0`` left out)."""

    ptr: NDArray[np.int64]
    slot: NDArray[np.int64]
    cell: NDArray[np.int64]


def counted_csr(
    visited: Mapping[TaxiId, frozenset[tuple[IntervalKey, int]]], taxis: Sequence[TaxiId], k0: int
) -> Counted:
    """The pairs each of ``taxis`` is counted in from interval ``k0`` on."""
    rows = [visited.get(taxi, ()) for taxi in taxis]
    sizes = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
    flat = chain.from_iterable(chain.from_iterable(rows))  # interval, cell, interval, cell, ...
    pairs = np.fromiter(flat, dtype=np.int64, count=2 * int(sizes.sum())).reshape(-1, 2)
    keep = pairs[:, 0] >= k0
    ptr = np.zeros(len(taxis) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(np.bincount(np.repeat(np.arange(len(rows)), sizes)[keep], minlength=len(rows)))
    return Counted(ptr, pairs[keep, 0] - k0, pairs[keep, 1].copy())


def counted_rows(counted: Counted, rows: NDArray[np.int64] | Sequence[int]) -> Counted:
    """The CSR of ``rows`` of ``counted``, in that order."""
    idx = np.asarray(rows, dtype=np.int64)
    lo, hi = counted.ptr[idx], counted.ptr[idx + 1]
    sizes = hi - lo
    ptr = np.zeros(len(idx) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(sizes)
    at = np.repeat(lo - ptr[:-1], sizes) + np.arange(int(ptr[-1]), dtype=np.int64)
    return Counted(ptr, counted.slot[at], counted.cell[at])


@compiled
def mark(zmask: NDArray[np.bool_], counted: Counted, i: int, value: bool) -> None:
    """Set the zero mask of taxi ``i`` of ``counted`` (``value`` True) or clear it (False)."""
    n_slots = zmask.shape[0]
    for p in range(counted.ptr[i], counted.ptr[i + 1]):
        s = counted.slot[p]
        if s < n_slots:
            zmask[s, counted.cell[p]] = value


@compiled_inline
def _slot(t: float, shift_s: float, interval_s: float, k0: int) -> int:
    return int(np.floor((t + shift_s) / interval_s)) - k0


@compiled
def eval_path(
    road_edges: Edges,
    gains: Gains,
    zmask: NDArray[np.bool_],
    stamp: NDArray[np.int64],
    stamp_id: int,
    edges: NDArray[np.int64],
    depart_s: float,
) -> tuple[float, int, float, float, int]:
    """Exact marginal gain of one path (Eq. 3): ``(gain, fixed-point gain, travel time, length, largest
    slot reached)``; a slot beyond the table is reported but gains nothing there. ``stamp`` (shape of the
    table, values below ``stamp_id`` on entry) records the pairs this path has entered."""
    term, term_q = gains.term, gains.term_q
    shift_s, interval_s, k0 = gains.shift_s, gains.interval_s, gains.k0
    time_s, length_m = road_edges.time_s, road_edges.length_m
    ec_ptr, ec_cell, ec_frac = road_edges.ec_ptr, road_edges.ec_cell, road_edges.ec_frac
    n_slots = term.shape[0]
    t = depart_s
    g = 0.0
    gq = 0
    length = 0.0
    max_slot = 0
    for i in range(
        edges.shape[0]
    ):  # the records' arrays taken out above: a read in the loop counts a reference
        e = edges[i]
        te = time_s[e]
        for j in range(ec_ptr[e], ec_ptr[e + 1]):
            slot = _slot(t + ec_frac[j] * te, shift_s, interval_s, k0)
            if slot > max_slot:
                max_slot = slot
            if slot >= n_slots:
                continue
            c = ec_cell[j]
            if stamp[slot, c] == stamp_id:
                continue
            stamp[slot, c] = stamp_id
            if not zmask[slot, c]:
                g += term[slot, c]
                gq += term_q[slot, c]
        t += te
        length += length_m[e]
    return g, gq, t - depart_s, length, max_slot


class TreeScratch(NamedTuple):
    """Scratch of ``eval_tree`` (n nodes, S x C table); ``tree_scratch`` makes one, and every call leaves it
    as it found it, so one serves a thread's calls."""

    first_kid: NDArray[np.int64]  # (n,) -1
    next_sib: NDArray[np.int64]  # (n,)
    first_of: NDArray[np.int64]  # (n,) -1: the first index in ``targets`` of a node
    in_union: NDArray[np.bool_]  # (n,) False
    members: NDArray[np.int64]  # (n,)
    st_node: NDArray[np.int64]  # (n + 1,) the depth-first stack
    st_next: NDArray[np.int64]
    st_log: NDArray[np.int64]
    st_t: NDArray[np.float64]
    st_g: NDArray[np.float64]
    st_l: NDArray[np.float64]
    st_ms: NDArray[np.int64]
    seen: NDArray[np.bool_]  # (S, C) False
    log_s: NDArray[np.int64]  # (S * C + 1,)
    log_c: NDArray[np.int64]


def tree_scratch(n_nodes: int, shape: tuple[int, int]) -> TreeScratch:
    """Scratch for ``eval_tree`` on a network of ``n_nodes`` and gain tables of ``shape``."""
    n = n_nodes
    cells = shape[0] * shape[1] + 1
    return TreeScratch(
        first_kid=np.full(n, -1, dtype=np.int64),
        next_sib=np.zeros(n, dtype=np.int64),
        first_of=np.full(n, -1, dtype=np.int64),
        in_union=np.zeros(n, dtype=np.bool_),
        members=np.zeros(n, dtype=np.int64),
        st_node=np.zeros(n + 1, dtype=np.int64),
        st_next=np.zeros(n + 1, dtype=np.int64),
        st_log=np.zeros(n + 1, dtype=np.int64),
        st_t=np.zeros(n + 1),
        st_g=np.zeros(n + 1),
        st_l=np.zeros(n + 1),
        st_ms=np.zeros(n + 1, dtype=np.int64),
        seen=np.zeros(shape, dtype=np.bool_),
        log_s=np.zeros(cells, dtype=np.int64),
        log_c=np.zeros(cells, dtype=np.int64),
    )


class TreeOut(NamedTuple):
    """Per target of ``eval_tree``: the gain, the travel time and the length of its tree path."""

    gain: NDArray[np.float64]
    time_s: NDArray[np.float64]
    length_m: NDArray[np.float64]


@compiled
def eval_tree(
    edges: Edges,
    gains: Gains,
    zmask: NDArray[np.bool_],
    pred: NDArray[np.int64],
    source: int,
    targets: NDArray[np.int64],
    depart_s: float,
    tree_scratch: TreeScratch,
    out: TreeOut,
) -> int:
    """``eval_path`` for the forward-tree path to every target at once: gain, time and length per target
    into ``out``; returns the largest slot reached (``pred`` holds the tree's edges on those paths, as
    ``unfolding.unfold`` writes them).

    The paths share their prefixes; a depth-first walk over the union of the paths carries each path's
    running state (time, gain, length, largest slot and the (slot, cell) pairs seen so far, undone on the
    way back up) from a node to its children. Every quantity is accumulated edge by edge from the source
    in travel order, as ``eval_path`` does along one path, so the results are bit-identical to it; the
    order in which siblings are visited does not matter.
    """
    k = targets.shape[0]
    out_g, out_t, out_l = out.gain, out.time_s, out.length_m
    first_kid = tree_scratch.first_kid
    next_sib = tree_scratch.next_sib
    first_of = tree_scratch.first_of
    n_mem = _tree_union(edges, pred, source, targets, tree_scratch)
    out_ms = np.zeros(k, dtype=np.int64)
    seen = tree_scratch.seen
    log_s = tree_scratch.log_s
    log_c = tree_scratch.log_c
    n_log = 0
    st_node = tree_scratch.st_node
    st_next = tree_scratch.st_next
    st_log = tree_scratch.st_log
    st_t = tree_scratch.st_t
    st_g = tree_scratch.st_g
    st_l = tree_scratch.st_l
    st_ms = tree_scratch.st_ms
    _tree_start(tree_scratch, source, depart_s, out)
    depth = 0
    while depth >= 0:
        w = st_next[depth]
        if w >= 0:
            st_next[depth] = next_sib[w]
            e = pred[w]
            t = st_t[depth]
            g = st_g[depth]
            ms = st_ms[depth]
            te = edges.time_s[e]
            start = n_log
            g, ms, n_log = _edge_cells(edges, gains, zmask, tree_scratch, e, t, g, ms, n_log)
            depth += 1
            st_node[depth] = w
            st_next[depth] = first_kid[w]
            st_log[depth] = start
            st_t[depth] = t + te
            st_g[depth] = g
            st_l[depth] = st_l[depth - 1] + edges.length_m[e]
            st_ms[depth] = ms
            i = first_of[w]
            if i >= 0:
                out_g[i] = g
                out_t[i] = (t + te) - depart_s
                out_l[i] = st_l[depth]
                out_ms[i] = ms
        else:
            for q in range(st_log[depth], n_log):
                seen[log_s[q], log_c[q]] = False
            n_log = st_log[depth]
            depth -= 1
    max_slot = _repeated(first_of, targets, out, out_ms)
    _tree_restore(edges, pred, targets, tree_scratch, n_mem)
    return max_slot


@compiled_inline
def _tree_start(tree_scratch: TreeScratch, source: int, depart_s: float, out: TreeOut) -> None:
    """Put the source on ``eval_tree``'s depth-first stack (at ``depart_s``, nothing gained or travelled)
    and give a target at the source the empty path."""
    tree_scratch.st_node[0] = source
    tree_scratch.st_next[0] = tree_scratch.first_kid[source]
    tree_scratch.st_log[0] = 0
    tree_scratch.st_t[0] = depart_s
    tree_scratch.st_g[0] = 0.0
    tree_scratch.st_l[0] = 0.0
    tree_scratch.st_ms[0] = 0
    if tree_scratch.first_of[source] >= 0:  # a target at the source: the empty path
        i = tree_scratch.first_of[source]
        out.gain[i] = 0.0
        out.time_s[i] = 0.0
        out.length_m[i] = 0.0


@compiled_inline
def _edge_cells(
    edges: Edges,
    gains: Gains,
    zmask: NDArray[np.bool_],
    tree_scratch: TreeScratch,
    e: int,
    t: float,
    graph: float,
    ms: int,
    n_log: int,
) -> tuple[float, int, int]:
    """Carry ``eval_tree``'s running state along edge ``e`` entered at time ``t``: each cell it enters adds
    its gain the first time its (slot, cell) pair is seen on the path (logged in ``tree_scratch`` to be undone
    on the way back up), and the largest slot reached grows. Returns the gain, the largest slot and the log's
    length after the edge."""
    te = edges.time_s[e]
    n_slots = gains.term.shape[0]
    seen, log_s, log_c = tree_scratch.seen, tree_scratch.log_s, tree_scratch.log_c
    for j in range(edges.ec_ptr[e], edges.ec_ptr[e + 1]):
        slot = _slot(t + edges.ec_frac[j] * te, gains.shift_s, gains.interval_s, gains.k0)
        if slot > ms:
            ms = slot
        if slot >= n_slots:
            continue
        c = edges.ec_cell[j]
        if seen[slot, c]:
            continue
        seen[slot, c] = True
        log_s[n_log] = slot
        log_c[n_log] = c
        n_log += 1
        if not zmask[slot, c]:
            graph += gains.term[slot, c]
    return graph, ms, n_log


@compiled_inline
def _tree_union(
    edges: Edges, pred: NDArray[np.int64], source: int, targets: NDArray[np.int64], tree_scratch: TreeScratch
) -> int:
    """Link the union of the tree paths to ``targets`` as child lists in ``tree_scratch`` (``first_of``: a
    target node's first index); returns how many nodes it holds (listed in ``tree_scratch.members``)."""
    first_kid, next_sib, first_of, in_union, members = (
        tree_scratch.first_kid,
        tree_scratch.next_sib,
        tree_scratch.first_of,
        tree_scratch.in_union,
        tree_scratch.members,
    )
    n_mem = 0
    for i in range(targets.shape[0]):
        v = targets[i]
        if first_of[v] < 0:
            first_of[v] = i
        while v != source and not in_union[v]:
            in_union[v] = True
            members[n_mem] = v
            n_mem += 1
            p = edges.tail[pred[v]]
            next_sib[v] = first_kid[p]
            first_kid[p] = v
            v = p
    return n_mem


@compiled_inline
def _repeated(
    first_of: NDArray[np.int64], targets: NDArray[np.int64], out: TreeOut, out_ms: NDArray[np.int64]
) -> int:
    """A repeated target gets the results of its first occurrence; returns the largest slot reached."""
    max_slot = 0
    for i in range(targets.shape[0]):
        f = first_of[targets[i]]
        if f != i:  # a repeated target: the result of its first occurrence
            out.gain[i] = out.gain[f]
            out.time_s[i] = out.time_s[f]
            out.length_m[i] = out.length_m[f]
            out_ms[i] = out_ms[f]
        if out_ms[i] > max_slot:
            max_slot = out_ms[i]
    return max_slot


@compiled_inline
def _tree_restore(
    edges: Edges, pred: NDArray[np.int64], targets: NDArray[np.int64], tree_scratch: TreeScratch, n_mem: int
) -> None:
    """Leave the scratch as ``_tree_union`` found it."""
    for q in range(n_mem):
        v = tree_scratch.members[q]
        tree_scratch.in_union[v] = False
        tree_scratch.first_kid[edges.tail[pred[v]]] = -1
    for i in range(targets.shape[0]):
        tree_scratch.first_of[targets[i]] = -1


@compiled_inline
def _mask_for(zmask: NDArray[np.bool_], counted: Counted, current: int, a: int) -> int:
    """Move the zero mask from taxi ``current`` (-1: none) to taxi ``a`` (nothing when they are the same);
    returns ``a``. Pairs taken grouped by taxi set each taxi's mask once."""
    if a != current:
        if current >= 0:
            mark(zmask, counted, current, False)
        mark(zmask, counted, a, True)
    return a


@compiled
def eval_pairs(
    edges: Edges,
    gains: Gains,
    counted: Counted,
    pair_taxi: NDArray[np.int64],
    pair_leg: NDArray[np.int64],
    pair_depart: NDArray[np.float64],
    leg_ptr: NDArray[np.int64],
    leg_edges: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.int64], int]:
    """``eval_path`` of leg ``pair_leg[k]`` for taxi ``pair_taxi[k]`` (a row of ``counted``) leaving at
    ``pair_depart[k]``, for every pair k (grouped by taxi, so each zero mask is set once): gains,
    fixed-point gains and the largest slot reached."""
    k = pair_taxi.shape[0]
    zmask = np.zeros(gains.term.shape, dtype=np.bool_)
    stamp = np.zeros(gains.term.shape, dtype=np.int64)
    out_g = np.zeros(k)
    out_q = np.zeros(k, dtype=np.int64)
    max_slot = 0
    order = np.argsort(pair_taxi, kind="mergesort")
    current = -1
    for r in range(k):
        q = order[r]
        current = _mask_for(zmask, counted, current, pair_taxi[q])
        leg = pair_leg[q]
        g, gq, _t, _l, ms = eval_path(
            edges, gains, zmask, stamp, r + 1, leg_edges[leg_ptr[leg] : leg_ptr[leg + 1]], pair_depart[q]
        )
        out_g[q] = g
        out_q[q] = gq
        if ms > max_slot:
            max_slot = ms
    return out_g, out_q, max_slot


@compiled
def pair_gains_q(
    road_edges: Edges,
    gains: Gains,
    counted: Counted,
    pair_taxi: NDArray[np.int64],
    pair_leg: NDArray[np.int64],
    pair_depart: NDArray[np.float64],
    leg_ptr: NDArray[np.int64],
    leg_edges: NDArray[np.int64],
) -> tuple[NDArray[np.int64], int]:
    """``eval_pairs``' fixed-point gains and largest slot (the same integers), without walking every
    crossing of every pair.

    A leg's crossings are timed in order from the departure (their computed times never decrease), so
    when the departure and an upper bound on the last crossing's time (the leg's travel time plus more
    than the rounding of the running sum) fall in one slot, every crossing falls in it: the pair's gain is
    then the sum of that slot's fixed-point terms over the leg's distinct cells the taxi is not counted in,
    and integer sums do not depend on the order of addition. Other pairs (a leg across an interval's end)
    are walked by ``eval_path``."""
    k = pair_taxi.shape[0]
    n_slots, n_cells = gains.term.shape
    n_legs = leg_ptr.shape[0] - 1
    cell_ptr = np.zeros(n_legs + 1, dtype=np.int64)
    n_total = 0
    for e in leg_edges:
        n_total += road_edges.ec_ptr[e + 1] - road_edges.ec_ptr[e]
    cells = np.empty(n_total, dtype=np.int64)  # each leg's distinct cells (at most its crossings)
    leg_s = np.zeros(n_legs)
    for leg in range(n_legs):
        edges = leg_edges[leg_ptr[leg] : leg_ptr[leg + 1]]
        mine = distinct_cells(road_edges, edges, n_cells)
        cell_ptr[leg + 1] = cell_ptr[leg] + mine.shape[0]
        cells[cell_ptr[leg] : cell_ptr[leg + 1]] = mine
        leg_s[leg] = road_edges.time_s[edges].sum()
    zmask = np.zeros(gains.term.shape, dtype=np.bool_)
    stamp = np.zeros(gains.term.shape, dtype=np.int64)
    out_q = np.zeros(k, dtype=np.int64)
    max_slot = 0
    order = np.argsort(pair_taxi, kind="mergesort")
    current = -1
    for r in range(k):
        q = order[r]
        current = _mask_for(zmask, counted, current, pair_taxi[q])
        leg = pair_leg[q]
        lo, hi = cell_ptr[leg], cell_ptr[leg + 1]
        if hi == lo:
            continue  # no crossing: no gain, slot 0
        depart = pair_depart[q]
        steps = leg_ptr[leg + 1] - leg_ptr[leg] + 2
        slack = (abs(depart) + leg_s[leg]) * 4.5e-16 * steps + 1e-3  # > the running sum's rounding
        slot = _slot(depart, gains.shift_s, gains.interval_s, gains.k0)
        if slot == _slot(depart + (leg_s[leg] + slack), gains.shift_s, gains.interval_s, gains.k0):
            if slot > max_slot:
                max_slot = slot
            if slot < n_slots:
                gq = 0
                for p in range(lo, hi):
                    c = cells[p]
                    if not zmask[slot, c]:
                        gq += gains.term_q[slot, c]
                out_q[q] = gq
        else:
            _g, gq, _t, _l, ms = eval_path(
                road_edges, gains, zmask, stamp, r + 1, leg_edges[leg_ptr[leg] : leg_ptr[leg + 1]], depart
            )
            out_q[q] = gq
            if ms > max_slot:
                max_slot = ms
    return out_q, max_slot


@compiled
def distinct_cells(road_edges: Edges, edges: NDArray[np.int64], n_cells: int) -> NDArray[np.int64]:
    """The distinct cells the edges cross, in order of first crossing (a path's G-route)."""
    seen = np.zeros(n_cells, dtype=np.bool_)
    out = np.empty(n_cells, dtype=np.int64)
    n = 0
    for e in edges:
        for j in range(road_edges.ec_ptr[e], road_edges.ec_ptr[e + 1]):
            c = road_edges.ec_cell[j]
            if not seen[c]:
                seen[c] = True
                out[n] = c
                n += 1
    return out[:n]


@compiled
def _first_pairs(
    road_edges: Edges,
    edges: NDArray[np.int64],
    depart_s: float,
    shift_s: float,
    interval_s: float,
    n_cells: int,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The distinct (interval, cell) pairs a path enters, in order of first entry."""
    total = 0
    for e in edges:
        total += road_edges.ec_ptr[e + 1] - road_edges.ec_ptr[e]
    ks = np.empty(total, dtype=np.int64)
    cs = np.empty(total, dtype=np.int64)
    n = 0
    run = 0.0
    for i in range(edges.shape[0]):
        e = edges[i]
        te = road_edges.time_s[e]
        start = depart_s + run
        for j in range(road_edges.ec_ptr[e], road_edges.ec_ptr[e + 1]):
            ks[n] = np.int64(np.floor((start + road_edges.ec_frac[j] * te + shift_s) / interval_s))
            cs[n] = road_edges.ec_cell[j]
            n += 1
        run += te
    if n == 0:
        return ks, cs
    k_min = ks.min()
    seen = np.zeros((ks.max() - k_min + 1, n_cells), dtype=np.bool_)
    out_k = np.empty(n, dtype=np.int64)
    out_c = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if not seen[ks[i] - k_min, cs[i]]:
            seen[ks[i] - k_min, cs[i]] = True
            out_k[m] = ks[i]
            out_c[m] = cs[i]
            m += 1
    return out_k[:m], out_c[:m]


@compiled
def path_facts(
    road_edges: Edges,
    ptr: NDArray[np.int64],
    flat: NDArray[np.int64],
    depart_s: float,
    shift_s: float,
    interval_s: float,
    n_cells: int,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """For every path of a CSR (all leaving at ``depart_s``): its G-route (distinct cells in first-crossing
    order) and its timed G-route (``timed_pairs``), as CSRs
    ``(cell_ptr, cells, pair_ptr, pair_k, pair_c)``."""
    n = ptr.shape[0] - 1
    cell_ptr = np.zeros(n + 1, dtype=np.int64)
    pair_ptr = np.zeros(n + 1, dtype=np.int64)
    cells_parts = []
    k_parts = []
    c_parts = []
    for i in range(n):
        edges = flat[ptr[i] : ptr[i + 1]]
        cs = distinct_cells(road_edges, edges, n_cells)
        cells_parts.append(cs)
        cell_ptr[i + 1] = cell_ptr[i] + cs.shape[0]
        if edges.shape[0] == 0:
            ks = np.empty(0, dtype=np.int64)
            cc = np.empty(0, dtype=np.int64)
        else:
            ks, cc = _first_pairs(road_edges, edges, depart_s, shift_s, interval_s, n_cells)
        k_parts.append(ks)
        c_parts.append(cc)
        pair_ptr[i + 1] = pair_ptr[i] + ks.shape[0]
    cells = np.empty(cell_ptr[n], dtype=np.int64)
    pair_k = np.empty(pair_ptr[n], dtype=np.int64)
    pair_c = np.empty(pair_ptr[n], dtype=np.int64)
    for i in range(n):
        cells[cell_ptr[i] : cell_ptr[i + 1]] = cells_parts[i]
        pair_k[pair_ptr[i] : pair_ptr[i + 1]] = k_parts[i]
        pair_c[pair_ptr[i] : pair_ptr[i + 1]] = c_parts[i]
    return cell_ptr, cells, pair_ptr, pair_k, pair_c


def timed_pairs(city: City, edges: NDArray[np.int64], depart_s: float) -> list[tuple[IntervalKey, int]]:
    """The (interval, cell) pairs a path leaving at ``depart_s`` enters, in order of first entry: what
    ``sensing.timed_cells(...).pairs()`` computes, by a kernel (same crossing times, same order)."""
    edges = np.asarray(edges, dtype=np.int64)
    if len(edges) == 0:
        return []
    shift = city.horizon.shift_s(float(depart_s))
    ks, cs = _first_pairs(
        road_graph(city).edges,
        edges,
        float(depart_s),
        shift,
        float(city.horizon.interval_s),
        city.grid.n_cells,
    )
    return [(IntervalKey(k), c) for k, c in zip(ks.tolist(), cs.tolist(), strict=True)]


def fixed_point_unit(top_term: float, terms_per_path: int, bits: int = 48) -> float:
    """The unit with which a path of ``terms_per_path`` terms, each at most ``top_term``, sums to at most
    about ``2**bits`` units (the assignments add up to 2**11 such sums in int64)."""
    return top_term * max(terms_per_path, 1) / 2.0**bits if top_term > 0 else 1.0
