"""Algorithm 1: the enhanced A* drive-by sensing route from a taxi to a POI (docs/METHOD.md section 5).

For one taxi and one POI, each kappa of the family (default 0, 0.3, 0.6, 0.9) gives the shortest path
under the utility-discounted edge cost ``c_e = t_e (1 - kappa u_e / max u)``, ``u_e`` the first slot's
marginal terms of the cells edge ``e`` enters, for this taxi (zero where it is already counted); the
route kept is the one with the largest phi = gain / time (Eq. 12), ties to the smaller kappa, so kappa = 0
(the fastest path) wins unless beaten. Costs are fixed for the epoch, so one canonical shortest-path tree
per (taxi, kappa) serves every POI at once (the straight-line A* heuristic would only prune the search:
the canonical path it returns is the same). Every candidate route is evaluated exactly (``gains``).

The kappa = 0 cost is the travel time whatever the taxi, and a taxi's kappa > 0 cost is the base cost (no
cell zeroed) except on the edges entering a cell it is counted in, where it is higher. So when an epoch has
fewer POIs than taxis, the routes come from one in-tree per POI and kappa instead of one tree per taxi and
kappa, and a taxi searches on its own only for a kappa whose in-tree route to some POI enters one of its
counted cells: the canonical path (``services.graph``) under the base costs avoids every edge where the
taxi's costs differ and those are nowhere lower, so it is the taxi's canonical path too. Both ways give the
same routes, and the tests check it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from services import search
from services.gains import (
    Counted,
    Gains,
    TreeScratch,
    entered_utility,
    eval_path,
    eval_tree,
    mark,
    tree_scratch,
)
from services.graph import INF, CellEdges, Costs, Edges, RoadGraph, SearchGraph, prepare_into
from services.jit import compiled, compiled_inline
from services.pads import Pad, Pads
from services.parallel import parallel_map

__all__ = ["Plans", "Route", "Scratch", "scratch", "plan_routes", "plan_one", "route_pair", "kappa_metric"]


GUIDED_PER_TREE = 16
"""About how many goal-directed searches (``search.run_guided``) from a taxi to one POI cost as much as one
tree from the taxi to every POI, on a metropolitan street grid (``bench/bench_epoch.py``); only speed
depends on it."""


class Scratch(NamedTuple):
    """One thread's scratch: a zero mask and an evaluation stamp over the gain table and the next stamp,
    the entered utility and one kappa metric per edge and super-edge, and the tree evaluation's scratch."""

    zmask: NDArray[np.bool_]
    stamp: NDArray[np.int64]
    next_stamp: NDArray[np.int64]  # (1,)
    u: NDArray[np.float64]  # (m,)
    edge_cost: NDArray[np.int64]  # (m,)
    se_cost: NDArray[np.int64]  # (S,) forward super-edges
    tree: TreeScratch


def _scratch(graph: RoadGraph, gn: Gains) -> Scratch:
    shape = gn.term.shape
    return Scratch(
        np.zeros(shape, np.bool_),
        np.zeros(shape, np.int64),
        np.ones(1, np.int64),
        np.zeros(graph.n_edges),
        np.zeros(graph.n_edges, np.int64),
        np.zeros(graph.forward.se_tail.shape[0], np.int64),
        tree_scratch(graph.n_nodes, shape),
    )


@compiled_inline
def _kappa_cost(t: float, u: float, umax: float, kappa: float) -> int:
    c = t * (1.0 - kappa * (u / umax)) if kappa != 0.0 else t
    q = int(np.rint(c * 1e6))
    return q if q > 1 else 1


@compiled
def kappa_metric(
    ed: Edges,
    g: SearchGraph,
    u: NDArray[np.float64],
    umax: float,
    kappa: float,
    edge_cost: NDArray[np.int64],
    se_cost: NDArray[np.int64],
) -> Costs:
    """Algorithm 1's edge cost ``c_e = t_e (1 - kappa u_e / umax)`` in whole microseconds (at least 1) into
    ``edge_cost``, prepared for ``g`` (its super-edge sums into ``se_cost``)."""
    for e in range(edge_cost.shape[0]):
        edge_cost[e] = _kappa_cost(ed.time_s[e], u[e], umax, kappa)
    return prepare_into(g, edge_cost, se_cost)


@compiled
def _eval_walk(
    ed: Edges, gn: Gains, sc: Scratch, succ: NDArray[np.int64], start: int, root: int, depart_s: float
) -> tuple[float, float, float, int, bool]:
    """``gains.eval_path`` along the in-tree path from ``start`` to ``root`` (same operations, same order),
    and whether the path enters a cell the taxi is counted in during the first slot (its zero mask's row 0):
    only on such an edge can the taxi's own kappa metric differ from the base one (``_patch``)."""
    n_slots = gn.term.shape[0]
    sid = sc.next_stamp[0]
    sc.next_stamp[0] = sid + 1
    t = depart_s
    g = 0.0
    length = 0.0
    max_slot = 0
    touched = False
    x = start
    while x != root:
        e = succ[x]
        te = ed.time_s[e]
        first = ed.ec_ptr[e]
        for j in range(first, ed.ec_ptr[e + 1]):
            c = ed.ec_cell[j]
            if j > first and sc.zmask[0, c]:
                touched = True
            slot = int(np.floor((t + ed.ec_frac[j] * te + gn.shift_s) / gn.interval_s)) - gn.k0
            if slot > max_slot:
                max_slot = slot
            if slot >= n_slots:
                continue
            if sc.stamp[slot, c] == sid:
                continue
            sc.stamp[slot, c] = sid
            if not sc.zmask[slot, c]:
                g += gn.term[slot, c]
        t += te
        length += ed.length_m[e]
        x = ed.head[e]
    return g, t - depart_s, length, max_slot, touched


@compiled
def _to_root(
    ed: Edges,
    rg: SearchGraph,
    ws: search.Workspace,
    costs: Costs,
    gn: Gains,
    sc: Scratch,
    counted: Counted,
    sources: NDArray[np.int64],
    root: int,
    depart_s: float,
    q: int,
    j: int,
    out_g: NDArray[np.float64],
    out_t: NDArray[np.float64],
    out_l: NDArray[np.float64],
    out_ms: NDArray[np.int64],
    touched: NDArray[np.int64],
    whole: bool,
    skip: NDArray[np.bool_],
) -> int:
    """The shortest path under ``costs`` (a metric shared by every taxi) from every source to ``root``
    (one in-tree; grown whole, or until every source is settled), each evaluated for its taxi into
    ``out_*[a, q, j]`` (but the sources marked ``skip``, left as they are); time NaN for a source that
    cannot reach the root; the largest slot the path reaches in ``out_ms[a, q, j]``. Lists in ``touched``
    the sources whose path enters a cell their taxi is counted in, and returns how many."""
    search.run(rg, ed, costs, root, INF, np.empty(0, dtype=np.int64) if whole else sources, ws)
    reached = np.empty(sources.shape[0], dtype=np.bool_)
    search.unfold_many(rg, ed, costs, INF, sources, ws, reached)
    n = 0
    for a in range(sources.shape[0]):
        if skip[a]:
            continue
        if not reached[a]:
            out_t[a, q, j] = np.nan
            continue
        mark(sc.zmask, counted, a, True)
        g, t, length, ms, touch = _eval_walk(ed, gn, sc, ws.pred, sources[a], root, depart_s)
        mark(sc.zmask, counted, a, False)
        out_g[a, q, j] = g
        out_t[a, q, j] = t
        out_l[a, q, j] = length
        out_ms[a, q, j] = ms
        if touch:
            touched[n] = a
            n += 1
    return n


class KappaBase(NamedTuple):
    """What every taxi's kappa metrics share in one epoch: the entered utility with no cell zeroed, its
    largest value and how many edges attain it, and the kappa metrics built from them (row q: kappa
    ``kappas[q]``; rows of kappa = 0 unused). A taxi's own metric differs only on the edges that enter a
    cell it is counted in (``_patch``); its utility there is lower, so its costs are higher: the base's
    cheapest super-edge still bounds its buckets from below, the travel time's dearest from above."""

    u: NDArray[np.float64]
    umax: float
    n_top: int
    edge: NDArray[np.int64]  # (kappas, m)
    se: NDArray[np.int64]  # (kappas, S)
    width: NDArray[np.int64]  # (kappas,)
    span: NDArray[np.int64]


@compiled
def _kappa_base(
    ed: Edges, fg: SearchGraph, time_costs: Costs, gn: Gains, kappas: NDArray[np.float64]
) -> KappaBase:
    zmask = np.zeros(gn.term.shape, dtype=np.bool_)
    m = ed.time_s.shape[0]
    u = np.zeros(m)
    umax = entered_utility(ed, gn, zmask, u)
    n_top = 0
    for e in range(m):
        if u[e] == umax:
            n_top += 1
    nk = kappas.shape[0]
    edge = np.zeros((nk, m), dtype=np.int64)
    se = np.zeros((nk, fg.se_tail.shape[0]), dtype=np.int64)
    width = np.ones(nk, dtype=np.int64)
    span = np.ones(nk, dtype=np.int64)
    time_max = 1
    for s in range(time_costs.se.shape[0]):
        if time_costs.se[s] > time_max:
            time_max = time_costs.se[s]
    for q in range(nk):
        if kappas[q] != 0.0 and umax > 0.0:
            c = kappa_metric(ed, fg, u, umax, kappas[q], edge[q], se[q])
            width[q] = c.width
            span[q] = time_max // c.width + 2
    return KappaBase(u, umax, n_top, edge, se, width, span)


class ReverseKappa(NamedTuple):
    """The base kappa metrics (``KappaBase``, no cell zeroed) prepared for the reverse graph: the POIs'
    in-trees under them (row q: kappa ``kappas[q]``; rows of kappa = 0 unused)."""

    se: NDArray[np.int64]  # (kappas, S reverse)
    width: NDArray[np.int64]
    span: NDArray[np.int64]


@compiled
def _reverse_kappa(rg: SearchGraph, base: KappaBase, kappas: NDArray[np.float64]) -> ReverseKappa:
    nk = kappas.shape[0]
    se = np.zeros((nk, rg.se_tail.shape[0]), dtype=np.int64)
    width = np.ones(nk, dtype=np.int64)
    span = np.ones(nk, dtype=np.int64)
    for q in range(nk):
        if kappas[q] != 0.0 and base.umax > 0.0:
            c = prepare_into(rg, base.edge[q], se[q])  # the base's edge costs, summed the reverse way
            width[q] = c.width
            span[q] = c.span
    return ReverseKappa(se, width, span)


class KappaWork(NamedTuple):
    """A thread's copy of the base metrics, patched for one taxi at a time and restored after."""

    edge: NDArray[np.int64]
    se: NDArray[np.int64]
    u: NDArray[np.float64]
    dirty: NDArray[np.int64]  # (m,) the patched edges of the current taxi
    stamp: NDArray[np.int64]  # (m,) stamp[e] == next_stamp[0]: e already listed


def kappa_work(pad: Pad, base: KappaBase) -> KappaWork:
    """The pad's copy of ``base`` (its arrays kept in the pad, refilled from ``base``)."""
    key = ("kappa-work", base.edge.shape, base.se.shape)
    work = pad.extra.get(key)
    if not isinstance(work, KappaWork):
        m = base.u.shape[0]
        blank = np.zeros(m, np.int64)
        work = KappaWork(
            np.empty_like(base.edge), np.empty_like(base.se), np.empty_like(base.u), blank, blank.copy()
        )
        pad.extra[key] = work
    np.copyto(work.edge, base.edge)
    np.copyto(work.se, base.se)
    np.copyto(work.u, base.u)
    return work


@compiled
def _patch(
    ed: Edges,
    entering: CellEdges,
    se_of: NDArray[np.int64],
    gn: Gains,
    sc: Scratch,
    counted: Counted,
    i: int,
    kappas: NDArray[np.float64],
    base: KappaBase,
    work: KappaWork,
) -> int:
    """Turn ``work`` into taxi ``i``'s metrics: the entered utility of every edge that enters a cell the
    taxi is counted in during the first slot, recomputed with its zero mask (the sum ``entered_utility``
    makes, in the same order), and the kappa costs of those edges and of their super-edges (whole
    numbers: a super-edge's sum moves by the edge's change exactly). Returns how many edges were patched,
    or -1 when the taxi's largest utility is not the base's (every edge attaining it is zeroed): then the
    taxi needs its metrics built whole."""
    sid = sc.next_stamp[0]
    sc.next_stamp[0] = sid + 1
    n = 0
    for p in range(counted.ptr[i], counted.ptr[i + 1]):
        if counted.slot[p] != 0:
            continue
        c = counted.cell[p]
        for q in range(entering.ptr[c], entering.ptr[c + 1]):
            e = entering.edge[q]
            if work.stamp[e] != sid:
                work.stamp[e] = sid
                work.dirty[n] = e
                n += 1
    lost = 0
    for r in range(n):
        e = work.dirty[r]
        s = 0.0
        for j in range(ed.ec_ptr[e] + 1, ed.ec_ptr[e + 1]):
            c = ed.ec_cell[j]
            if not sc.zmask[0, c]:
                s += gn.term[0, c]
        work.u[e] = s
        if base.u[e] == base.umax and s < base.umax:
            lost += 1
    if lost == base.n_top:
        for r in range(n):
            work.u[work.dirty[r]] = base.u[work.dirty[r]]
        return -1
    for q in range(kappas.shape[0]):
        if kappas[q] == 0.0 or base.umax <= 0.0:
            continue
        for r in range(n):
            e = work.dirty[r]
            new = _kappa_cost(ed.time_s[e], work.u[e], base.umax, kappas[q])
            old = work.edge[q, e]
            if new != old:
                work.edge[q, e] = new
                work.se[q, se_of[e]] += new - old
    return n


@compiled
def _unpatch(se_of: NDArray[np.int64], base: KappaBase, work: KappaWork, n: int) -> None:
    """Restore ``work`` to the base after a taxi whose ``_patch`` listed ``n`` edges."""
    for r in range(n):
        e = work.dirty[r]
        work.u[e] = base.u[e]
        for q in range(base.edge.shape[0]):
            work.edge[q, e] = base.edge[q, e]
            work.se[q, se_of[e]] = base.se[q, se_of[e]]


PATCH_BYTES = 256 * 2**20
"""Most memory the taxis' own kappa costs may take when kept for the goal-directed searches
(``Patches``); beyond it each search patches its taxi's metrics afresh. Only speed depends on it."""


class Patches(NamedTuple):
    """Each taxi's own kappa costs where they differ from the base, as ``_patch`` makes them, kept for the
    goal-directed searches: a taxi is searched again for many (kappa, target) pairs, and patching it afresh
    each time (the entered utility recomputed, every kappa's costs) cost more than the search itself.
    Taxi ``a``'s patched edges are ``edge[ptr[a]:ptr[a] + n[a]]`` with cost ``cost[q, ...]`` under kappa
    ``q``; ``n[a]`` -1: its largest utility is not the base's (it searches on its own). ``ptr`` empty:
    nothing kept (each search patches afresh)."""

    ptr: NDArray[np.int64]  # (F,) start of each taxi's rows, room for every edge entering its cells
    n: NDArray[np.int64]  # (F,)
    edge: NDArray[np.int64]
    cost: NDArray[np.int64]  # (kappas, rows)


@compiled
def _keep_patches(
    ed: Edges,
    entering: CellEdges,
    se_of: NDArray[np.int64],
    gn: Gains,
    sc: Scratch,
    counted: Counted,
    kappas: NDArray[np.float64],
    base: KappaBase,
    work: KappaWork,
    chunk: NDArray[np.int64],
    kept: Patches,
) -> None:
    """``_patch`` each taxi of ``chunk`` and keep what it wrote in ``kept``; ``work`` is left as the base."""
    for a in chunk:
        mark(sc.zmask, counted, a, True)
        n = _patch(ed, entering, se_of, gn, sc, counted, a, kappas, base, work)
        kept.n[a] = n
        at = kept.ptr[a]
        for r in range(n):
            e = work.dirty[r]
            kept.edge[at + r] = e
            for q in range(kappas.shape[0]):
                kept.cost[q, at + r] = work.edge[q, e]
        _unpatch(se_of, base, work, n)
        mark(sc.zmask, counted, a, False)


@compiled_inline
def _apply(se_of: NDArray[np.int64], work: KappaWork, kept: Patches, a: int, q: int) -> None:
    """Turn ``work``'s kappa ``q`` row into taxi ``a``'s (the same integers ``_patch`` writes)."""
    at = kept.ptr[a]
    for r in range(at, at + kept.n[a]):
        e = kept.edge[r]
        new = kept.cost[q, r]
        old = work.edge[q, e]
        if new != old:
            work.edge[q, e] = new
            work.se[q, se_of[e]] += new - old


@compiled_inline
def _restore(
    se_of: NDArray[np.int64], base: KappaBase, work: KappaWork, kept: Patches, a: int, q: int
) -> None:
    """Undo ``_apply``."""
    at = kept.ptr[a]
    for r in range(at, at + kept.n[a]):
        e = kept.edge[r]
        work.edge[q, e] = base.edge[q, e]
        work.se[q, se_of[e]] = base.se[q, se_of[e]]


def keep_patches(
    graph: RoadGraph,
    gn: Gains,
    counted: Counted,
    kappas: NDArray[np.float64],
    base: KappaBase,
    skip: NDArray[np.bool_],
    workers: int,
    pads: Pads,
) -> Patches:
    """Every taxi's own kappa costs (``Patches``), but those marked ``skip``; nothing kept when they would
    take more than ``PATCH_BYTES``."""
    f = counted.ptr.shape[0] - 1
    per_cell = np.diff(graph.entering.ptr)
    first = counted.slot == 0  # only the first slot's counted cells change a taxi's costs (_patch)
    owner = np.repeat(np.arange(f), np.diff(counted.ptr))[first]
    room = np.bincount(owner, weights=per_cell[counted.cell[first]], minlength=f).astype(np.int64)
    room[skip] = 0
    rows = int(room.sum())
    n = np.full(f, -1, dtype=np.int64)
    if rows * (len(kappas) + 1) * 8 > PATCH_BYTES:
        return Patches(n[:0], n, n[:0], np.zeros((len(kappas), 0), dtype=np.int64))
    ptr = np.zeros(f, dtype=np.int64)
    ptr[1:] = np.cumsum(room)[:-1]
    kept = Patches(ptr, n, np.zeros(rows, dtype=np.int64), np.zeros((len(kappas), rows), dtype=np.int64))

    def fill(chunk: Sequence[int]) -> list[None]:
        with pads.take() as pad:
            _keep_patches(
                graph.edges, graph.entering, graph.se_of, gn, scratch(pad, gn), counted, kappas, base,
                kappa_work(pad, base), np.asarray(chunk, dtype=np.int64), kept,
            )  # fmt: skip
        return [None] * len(chunk)

    parallel_map(fill, np.flatnonzero(~skip).tolist(), workers)
    return kept


@compiled
def _plan_taxi(
    ed: Edges,
    fg: SearchGraph,
    ws: search.Workspace,
    time_costs: Costs,
    gn: Gains,
    sc: Scratch,
    kappas: NDArray[np.float64],
    source: int,
    targets: NDArray[np.int64],
    depart_s: float,
    have: NDArray[np.bool_],
    given_g: NDArray[np.float64],
    given_t: NDArray[np.float64],
    given_l: NDArray[np.float64],
    given_ms: NDArray[np.int64],
    out_k: NDArray[np.int64],
    out_g: NDArray[np.float64],
    out_t: NDArray[np.float64],
    out_l: NDArray[np.float64],
    base: KappaBase,
    work: KappaWork,
    patched: bool,
) -> int:
    """Algorithm 1 from one taxi (its zero mask set in ``sc``) to every target. Where ``have[q]`` the
    routes of kappa ``q`` are given (``given_*[q]``, from the targets' in-trees; NaN time: unreachable;
    ``given_ms``: the largest slot each reaches)
    and only the other kappas are searched. With ``patched`` the taxi's kappa metrics are ``work``'s rows
    (``_patch``), else they are built whole. Writes the chosen kappa's index (-1: unreachable), gain, time
    and length per target; returns the largest slot reached, or -1 when a target cannot be reached."""
    k = targets.shape[0]
    reached = np.empty(k, dtype=np.bool_)
    umax = base.umax if patched else entered_utility(ed, gn, sc.zmask, sc.u)
    best = np.full(k, -np.inf)
    g = np.zeros(k)
    t = np.zeros(k)
    length = np.zeros(k)
    max_slot = 0
    for ki in range(kappas.shape[0]):
        kappa = kappas[ki]
        if kappa != 0.0 and umax <= 0.0:
            continue  # no edge enters a cell of positive gain: every kappa gives the fastest path
        if have[ki]:
            for i in range(k):
                if np.isnan(given_t[ki, i]):
                    return -1
                g[i] = given_g[ki, i]
                t[i] = given_t[ki, i]
                length[i] = given_l[ki, i]
                if given_ms[ki, i] > max_slot:
                    max_slot = given_ms[ki, i]
        else:
            if kappa == 0.0:
                costs = time_costs
            elif patched:
                costs = Costs(work.edge[ki], work.se[ki], base.width[ki], base.span[ki])
            else:
                costs = kappa_metric(ed, fg, sc.u, umax, kappa, sc.edge_cost, sc.se_cost)
            search.run(fg, ed, costs, source, INF, targets, ws)
            if not search.unfold_many(fg, ed, costs, INF, targets, ws, reached):
                return -1
            ms = eval_tree(ed, gn, sc.zmask, ws.pred, source, targets, depart_s, sc.tree, g, t, length)
            if ms > max_slot:
                max_slot = ms
        for i in range(k):
            phi = g[i] / t[i] if t[i] > 0 else 0.0
            if phi > best[i]:
                best[i] = phi
                out_k[i] = ki
                out_g[i] = g[i]
                out_t[i] = t[i]
                out_l[i] = length[i]
    return max_slot


@compiled
def _roots_chunk(
    ed: Edges,
    fg: SearchGraph,
    rg: SearchGraph,
    wsf: search.Workspace,
    wsr: search.Workspace,
    time_costs: Costs,
    entering: CellEdges,
    se_of: NDArray[np.int64],
    base: KappaBase,
    rev: ReverseKappa,
    work: KappaWork,
    gn: Gains,
    sc: Scratch,
    counted: Counted,
    kappas: NDArray[np.float64],
    sources: NDArray[np.int64],
    targets: NDArray[np.int64],
    chunk: NDArray[np.int64],
    depart_s: float,
    out_g: NDArray[np.float64],
    out_t: NDArray[np.float64],
    out_l: NDArray[np.float64],
    out_ms: NDArray[np.int64],
    own: NDArray[np.bool_],
    touched0: NDArray[np.bool_],
    kept: Patches,
) -> int:
    """The routes of every source under the in-trees ``chunk`` (item ``q * P + j``: kappa ``q``, target
    ``j``) in one compiled call, into the (sources, kappas, targets) outputs; returns the number of
    goal-directed searches made.

    Kappa = 0 is the travel time for every taxi: its in-tree routes are every taxi's. For kappa > 0 the
    in-tree is grown under the base metric (no cell zeroed); a taxi whose route in it enters a cell the
    taxi is counted in has costs of its own there (``_patch``), higher, so its route is searched again
    under its own costs, goal-directed by the in-tree's labels (a lower bound that never drops by more than
    an edge's own label: ``search.run_guided`` finds the same canonical path as a plain search). A taxi
    whose largest utility is not the base's (``_patch`` -1), or marked ``own``, gets its kappa > 0 routes in
    ``_taxis_chunk`` (a taxi marked ``own`` is not evaluated in the kappa > 0 in-trees).
    ``touched0[a, j]``: taxi ``a``'s fastest route to target ``j`` enters one of its counted cells
    (written by the kappa = 0 in-trees).
    """
    p = targets.shape[0]
    todo = np.empty(sources.shape[0], dtype=np.int64)
    pot = np.empty((3, fg.kept.shape[0]), dtype=np.int64)
    keep = kept.ptr.shape[0] > 0
    no_landmarks = np.zeros((0, 0), dtype=np.int64)
    skip_none = np.zeros(sources.shape[0], dtype=np.bool_)
    guided = 0
    for item in chunk:
        q, j = item // p, item % p
        root = targets[j]
        if kappas[q] == 0.0:
            n = _to_root(
                ed, rg, wsr, time_costs, gn, sc, counted, sources, root, depart_s, q, j, out_g, out_t, out_l,
                out_ms, todo, False, skip_none,
            )  # fmt: skip
            for r in range(n):
                touched0[todo[r], j] = True
            continue
        costs = Costs(base.edge[q], rev.se[q], rev.width[q], rev.span[q])
        n = _to_root(
            ed, rg, wsr, costs, gn, sc, counted, sources, root, depart_s, q, j, out_g, out_t, out_l, out_ms,
            todo, True, own,
        )  # fmt: skip
        if n == 0:
            continue
        search.labels(rg, ed, costs, INF, fg.kept, wsr, pot)  # the in-tree's labels: run_guided's potential
        for r in range(n):
            a = todo[r]
            mark(sc.zmask, counted, a, True)
            if keep:
                patched = kept.n[a]
                if patched >= 0:
                    _apply(se_of, work, kept, a, q)
            else:
                patched = _patch(ed, entering, se_of, gn, sc, counted, a, kappas, base, work)
            if patched >= 0:
                mine = Costs(work.edge[q], work.se[q], base.width[q], base.span[q])
                search.run_guided(fg, ed, mine, sources[a], root, pot, wsf, no_landmarks)
                guided += 1
                if search.unfold(fg, ed, mine, INF, root, wsf):
                    edges = search.path_to(ed, 1, wsf.pred, sources[a], root)
                    sid = sc.next_stamp[0]
                    sc.next_stamp[0] = sid + 1
                    g, _gq, t, length, ms = eval_path(ed, gn, sc.zmask, sc.stamp, sid, edges, depart_s)
                    out_g[a, q, j] = g
                    out_t[a, q, j] = t
                    out_l[a, q, j] = length
                    out_ms[a, q, j] = ms
                else:
                    out_t[a, q, j] = np.nan
            if not keep:
                _unpatch(se_of, base, work, patched)
            elif patched >= 0:
                _restore(se_of, base, work, kept, a, q)
            mark(sc.zmask, counted, a, False)
    return guided


@compiled
def _taxis_chunk(
    ed: Edges,
    fg: SearchGraph,
    ws: search.Workspace,
    time_costs: Costs,
    entering: CellEdges,
    se_of: NDArray[np.int64],
    gn: Gains,
    sc: Scratch,
    counted: Counted,
    kappas: NDArray[np.float64],
    sources: NDArray[np.int64],
    targets: NDArray[np.int64],
    chunk: NDArray[np.int64],
    depart_s: float,
    from_roots: bool,
    root_g: NDArray[np.float64],
    root_t: NDArray[np.float64],
    root_l: NDArray[np.float64],
    root_ms: NDArray[np.int64],
    own: NDArray[np.bool_],
    out_k: NDArray[np.int64],
    out_g: NDArray[np.float64],
    out_t: NDArray[np.float64],
    out_l: NDArray[np.float64],
    base: KappaBase,
    work: KappaWork,
) -> tuple[int, int, int]:
    """Algorithm 1 for the taxis ``chunk`` (rows of the outputs) in one compiled call: each taxi's zero mask
    and patched metrics set, its targets planned, both undone. With ``from_roots`` the routes
    ``root_*[i]`` (``_roots_chunk``) are taken for kappa = 0 always, and for another kappa when the taxi's
    metric is the base one patched, unless it is marked ``own``; a taxi whose largest utility is not the
    base's searches those itself.
    Returns the largest slot reached, -1 or the first taxi that cannot reach a target, and how many
    (taxi, kappa) searches were run."""
    max_slot = 0
    nk = kappas.shape[0]
    have = np.zeros(nk, dtype=np.bool_)
    searched = 0
    for i in chunk:
        mark(sc.zmask, counted, i, True)
        n = _patch(ed, entering, se_of, gn, sc, counted, i, kappas, base, work)
        for q in range(nk):
            have[q] = from_roots and (kappas[q] == 0.0 or (n >= 0 and not own[i]))
            if not have[q] and (kappas[q] == 0.0 or base.umax > 0.0):
                searched += 1
        ms = _plan_taxi(
            ed, fg, ws, time_costs, gn, sc, kappas, sources[i], targets, depart_s, have, root_g[i], root_t[i],
            root_l[i], root_ms[i], out_k[i], out_g[i], out_t[i], out_l[i], base, work, n >= 0,
        )  # fmt: skip
        _unpatch(se_of, base, work, n)
        mark(sc.zmask, counted, i, False)
        if ms < 0:
            return 0, i, searched
        if ms > max_slot:
            max_slot = ms
    return max_slot, -1, searched


@dataclass(frozen=True, slots=True, eq=False)
class Plans:
    """Algorithm 1 from each of F taxis to each of P targets: the chosen kappa (index into ``kappas``),
    gain, travel time and length of the route, as (F, P) arrays, and the largest slot any route reached."""

    kappas: NDArray[np.float64]
    kappa_index: NDArray[np.int64]
    gain: NDArray[np.float64]
    time_s: NDArray[np.float64]
    length_m: NDArray[np.float64]
    max_slot: int
    in_trees: int = 0  # searches from the targets (one per kappa and target)
    guided_searches: int = 0  # goal-directed searches of taxis whose in-tree route enters a counted cell
    taxi_searches: int = 0  # searches from the taxis (one per taxi and kappa not served by the in-trees)

    @property
    def phi(self) -> NDArray[np.float64]:
        """phi = gain / time (Eq. 12); 0 for a zero-length route."""
        t = self.time_s
        return np.divide(self.gain, t, out=np.zeros_like(self.gain), where=t > 0)


def plan_routes(
    graph: RoadGraph,
    gn: Gains,
    counted: Counted,
    sources: NDArray[np.int64],
    targets: NDArray[np.int64],
    depart_s: float,
    kappas: Sequence[float],
    workers: int,
    pads: Pads,
    *,
    fastest_from_targets: bool | None = None,
) -> Plans:
    """Algorithm 1 from every source (taxi ``i``'s counted pairs in ``counted``) to every target.

    When there are fewer than half as many targets as sources (``fastest_from_targets`` forces the choice),
    the routes come from one in-tree per target and kappa under the metric every taxi shares (the travel
    time; the base kappa metric, no cell zeroed); a taxi whose in-tree route enters a cell it is counted in
    is searched again to that target under its own costs, goal-directed by the in-tree, and a taxi whose
    normalization is its own, or whose fastest routes enter its counted cells on the way to more than
    ``GUIDED_PER_TREE`` targets, searches its kappa > 0 trees itself; when fewer than twice as many taxis
    as targets are left to read them, no kappa > 0 in-trees are grown. The routes are the same either way:
    docs/DISPATCH.md proves it and the tests check it.

    Raises
    ------
    ValueError
        When a target cannot be reached from a source.
    """
    ed = graph.edges
    f, p = len(sources), len(targets)
    kap = np.asarray(kappas, dtype=np.float64)
    nk = len(kap)
    out_k = np.full((f, p), -1, dtype=np.int64)
    out_g = np.zeros((f, p))
    out_t = np.full((f, p), np.nan)
    out_l = np.zeros((f, p))
    from_roots = (0 < 2 * p < f) if fastest_from_targets is None else (fastest_from_targets and p > 0)
    base = _kappa_base(ed, graph.forward, graph.time_forward, gn, kap)
    pr = p if from_roots else 0  # the in-tree results (sources, kappas, targets), when there are any
    root_g = np.zeros((f, nk, pr))
    root_t = np.full((f, nk, pr), np.nan)
    root_l = np.zeros((f, nk, pr))
    root_ms = np.zeros((f, nk, pr), dtype=np.int64)
    guided = 0
    own = np.zeros(f, dtype=np.bool_)
    touched0 = np.zeros((f, pr), dtype=np.bool_)
    if from_roots:
        rev = _reverse_kappa(graph.reverse, base, kap)
        none = np.zeros(0, dtype=np.int64)
        kept = Patches(none, none, none, np.zeros((nk, 0), dtype=np.int64))

        def roots(chunk: Sequence[int]) -> list[int]:
            with pads.take() as pad:
                n = _roots_chunk(
                    ed, graph.forward, graph.reverse, pad.forward, pad.reverse, graph.time_reverse,
                    graph.entering, graph.se_of, base, rev, kappa_work(pad, base), gn, scratch(pad, gn),
                    counted, kap, sources, targets, np.asarray(chunk, dtype=np.int64), depart_s, root_g,
                    root_t, root_l, root_ms, own, touched0, kept,
                )  # fmt: skip
            return [n] + [0] * (len(chunk) - 1)

        fastest = [q * p + j for q in range(nk) if kap[q] == 0.0 for j in range(p)]
        parallel_map(roots, fastest, workers)
        # A taxi whose fastest routes enter its counted cells on the way to many targets will likely need
        # as many goal-directed searches per kappa: past GUIDED_PER_TREE of them, one tree of its own per
        # kappa is cheaper (speed only: both give the canonical routes).
        own = touched0.sum(axis=1) > GUIDED_PER_TREE
        rest = [q * p + j for q in range(nk) if kap[q] != 0.0 and base.umax > 0.0 for j in range(p)]
        if rest:
            kept = keep_patches(graph, gn, counted, kap, base, own, workers, pads)
            if len(kept.ptr):
                own |= kept.n < 0  # own normalization: these taxis search their kappa > 0 trees themselves
            if not 2 * p < f - int(own.sum()):
                # The kappa > 0 in-trees pay only while they serve twice as many taxis as there are
                # targets, as for kappa = 0 (speed only: both give the canonical routes).
                own[:] = True
                rest = []
        guided = sum(parallel_map(roots, rest, workers))
        trees = fastest + rest

    def taxis(chunk: Sequence[int]) -> list[tuple[int, int]]:
        with pads.take() as pad:
            ms, failed, searched = _taxis_chunk(
                ed, graph.forward, pad.forward, graph.time_forward, graph.entering, graph.se_of, gn,
                scratch(pad, gn), counted, kap, sources, targets, np.asarray(chunk, dtype=np.int64), depart_s,
                from_roots, root_g, root_t, root_l, root_ms, own, out_k, out_g, out_t, out_l, base,
                kappa_work(pad, base),
            )  # fmt: skip
        if failed >= 0:
            lost = np.isnan(root_t[failed][kap == 0.0]).any(axis=0) if from_roots else out_k[failed] < 0
            missing = targets[lost]
            raise ValueError(f"targets unreachable from node {int(sources[failed])}: {missing[:5].tolist()}")
        return [(ms, searched)] + [(0, 0)] * (len(chunk) - 1)

    done = parallel_map(taxis, range(f), workers)
    return Plans(
        kap,
        out_k,
        out_g,
        out_t,
        out_l,
        max((ms for ms, _ in done), default=0),
        len(trees) if from_roots else 0,
        guided,
        sum(n for _, n in done),
    )


def scratch(pad: Pad, gn: Gains) -> Scratch:
    """The pad's scratch for Algorithm 1 with tables shaped like ``gn`` (made on first need)."""
    key = ("algorithm1", gn.term.shape)
    got = pad.extra.get(key)
    if not isinstance(got, Scratch):
        got = pad.extra[key] = _scratch(pad.graph, gn)
    return got


@compiled
def _kappa_metric(
    ed: Edges, fg: SearchGraph, time_costs: Costs, sc: Scratch, umax: float, kappa: float
) -> Costs:
    """The kappa metric of the taxi whose zero mask and entered utility ``sc`` holds."""
    if kappa == 0.0 or umax <= 0.0:
        return time_costs
    return kappa_metric(ed, fg, sc.u, umax, kappa, sc.edge_cost, sc.se_cost)


@compiled
def _path(
    ed: Edges, fg: SearchGraph, ws: search.Workspace, costs: Costs, source: int, target: int
) -> NDArray[np.int64]:
    """The canonical path from ``source`` to ``target`` under ``costs`` (empty and ``ws.info[1] == -1``
    when it cannot be reached)."""
    tgt = np.empty(1, dtype=np.int64)
    tgt[0] = target
    search.run(fg, ed, costs, source, INF, tgt, ws)
    if not search.unfold(fg, ed, costs, INF, target, ws):
        ws.info[1] = -1
        return np.empty(0, dtype=np.int64)
    return search.path_to(ed, 1, ws.pred, source, target)


@compiled
def _route_pair(
    ed: Edges,
    fg: SearchGraph,
    ws: search.Workspace,
    time_costs: Costs,
    gn: Gains,
    sc: Scratch,
    counted: Counted,
    i: int,
    source: int,
    target: int,
    kappa: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64], bool]:
    """Taxi ``i``'s kappa route and fastest path from ``source`` to ``target`` (the canonical paths its trees
    in ``plan_routes`` hold), and whether both were reached."""
    mark(sc.zmask, counted, i, True)
    umax = entered_utility(ed, gn, sc.zmask, sc.u)
    mark(sc.zmask, counted, i, False)
    fastest = _path(ed, fg, ws, time_costs, source, target)
    ok = ws.info[1] != -1
    if kappa == 0.0 or umax <= 0.0:
        return fastest, fastest, ok
    route = _path(ed, fg, ws, _kappa_metric(ed, fg, time_costs, sc, umax, kappa), source, target)
    return route, fastest, ok and ws.info[1] != -1


def route_pair(
    graph: RoadGraph,
    gn: Gains,
    counted: Counted,
    i: int,
    source: int,
    target: int,
    kappa: float,
    pad: Pad,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Taxi ``i``'s kappa route and its fastest path from ``source`` to ``target``: the canonical paths its
    trees in ``plan_routes`` held (found again rather than kept: a tree per taxi and kappa is too much
    memory at metropolitan scale).

    Raises
    ------
    ValueError
        When ``target`` cannot be reached.
    """
    route, fastest, ok = _route_pair(
        graph.edges, graph.forward, pad.forward, graph.time_forward, gn, scratch(pad, gn), counted, i, source,
        target, float(kappa),
    )  # fmt: skip
    if not ok:
        raise ValueError(f"node {target} cannot be reached from node {source}")
    return route, fastest


@dataclass(frozen=True, slots=True)
class Route:
    """One monitoring route: the kappa chosen, its edges and their exact evaluation."""

    source: int
    target: int
    kappa: float
    edges: NDArray[np.int64]
    gain: float
    time_s: float
    length_m: float
    max_slot: int

    @property
    def efficiency(self) -> float:
        """phi = gain / travel time (Eq. 12); 0 for a zero-length route."""
        return self.gain / self.time_s if self.time_s > 0 else 0.0


@compiled
def _plan_one(
    ed: Edges,
    fg: SearchGraph,
    ws: search.Workspace,
    time_costs: Costs,
    gn: Gains,
    sc: Scratch,
    counted: Counted,
    i: int,
    kappas: NDArray[np.float64],
    source: int,
    target: int,
    fastest: NDArray[np.int64],
    depart_s: float,
) -> tuple[int, NDArray[np.int64], float, float, float, int]:
    """``plan_one`` in one compiled call: (kappa index (-1: unreachable), edges, gain, time, length, largest
    slot) of the best route."""
    mark(sc.zmask, counted, i, True)
    umax = entered_utility(ed, gn, sc.zmask, sc.u)
    best_phi = -np.inf
    best_k = -1
    best_edges = fastest
    best_g = 0.0
    best_t = 0.0
    best_l = 0.0
    best_ms = 0
    for ki in range(kappas.shape[0]):
        kappa = kappas[ki]
        if kappa == 0.0:
            edges = fastest
        elif umax > 0.0:
            edges = _path(ed, fg, ws, _kappa_metric(ed, fg, time_costs, sc, umax, kappa), source, target)
            if ws.info[1] == -1:
                best_k = -1
                break
        else:
            continue
        sid = sc.next_stamp[0]
        sc.next_stamp[0] = sid + 1
        g, _gq, t, length, ms = eval_path(ed, gn, sc.zmask, sc.stamp, sid, edges, depart_s)
        phi = g / t if t > 0 else 0.0
        if phi > best_phi:
            best_phi = phi
            best_k = ki
            best_edges = edges
            best_g = g
            best_t = t
            best_l = length
            best_ms = ms
    mark(sc.zmask, counted, i, False)
    return best_k, best_edges, best_g, best_t, best_l, best_ms


def plan_one(
    graph: RoadGraph,
    gn: Gains,
    counted: Counted,
    i: int,
    source: int,
    target: int,
    fastest: NDArray[np.int64],
    kappas: Sequence[float],
    depart_s: float,
    pad: Pad,
) -> Route:
    """Algorithm 1 from taxi ``i`` to one target, its fastest path given (the kappa = 0 cost is the travel
    time whatever the gains, so the fastest path does not change when the gains do)."""
    kap = np.asarray(kappas, dtype=np.float64)
    ki, edges, g, t, length, ms = _plan_one(
        graph.edges, graph.forward, pad.forward, graph.time_forward, gn, scratch(pad, gn), counted, i, kap,
        int(source), int(target), np.asarray(fastest, dtype=np.int64), float(depart_s),
    )  # fmt: skip
    if ki < 0:
        raise ValueError(f"node {target} cannot be reached from node {source}")
    return Route(int(source), int(target), float(kap[ki]), edges, float(g), float(t), float(length), int(ms))
