"""Algorithm 1: the enhanced A* drive-by sensing route from a taxi to a POI (docs/METHOD.md section 5).

For one taxi and one POI, each kappa of the family (default 0, 0.3, 0.6, 0.9) gives the shortest path
under the utility-discounted edge cost ``c_e = t_e (1 - kappa u_e / max u)``, ``u_e`` the first slot's
marginal terms of the cells edge ``e`` enters, for this taxi (zero where it is already counted); the
route kept is the one with the largest phi = gain / time (Eq. 12), ties to the smaller kappa, so kappa = 0
(the fastest path) wins unless beaten. Costs are fixed for the epoch, so one canonical shortest-path tree
per (taxi, kappa) serves every POI at once (the straight-line A* heuristic would only prune the search:
the canonical path it returns is the same). Every candidate route is evaluated exactly (``gains``).

Step 3 considers a (taxi, POI) pair when the POI lies within the reach of the taxi (its fastest path takes
at most ``reach_us``; ``graph.INF``: every pair), so every search is bounded: the fastest paths by the
reach, a taxi's discounted routes by its farthest POI in reach (a route's discounted cost is at most the
travel time of the fastest path, since no edge costs more than its travel time).

The kappa = 0 cost is the travel time whatever the taxi, and a taxi's kappa > 0 cost is the *base* cost
(no cell zeroed) except on the edges entering a cell it is counted in, where it is higher, unless its
largest utility is not the base's (every edge of the largest utility enters a cell it is counted in: its
own normalization). So when an epoch has fewer POIs than taxis, the routes come from one in-tree per POI
and kappa instead of one tree per taxi and kappa, and a taxi searches again only where its in-tree route
enters one of its counted cells: the canonical path (``services.network.graph``) under the base costs avoids
every edge where the taxi's costs differ, and those are nowhere lower, so it is the taxi's canonical path too.
Both ways give the same routes, and the tests check it. A taxi's own costs are computed as its searches
reach each edge (``graph.Lazy``), never for the whole network; when many taxis grow their own trees, the
base costs of the super-edges that enter a cell are computed once for the epoch (``Overlay``) and a taxi's
trees compute only those entering its counted cells, the same integers either way.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.kernel.parallel import default_workers, parallel_map
from services.network import astar, dijkstra, heaps, point_to_point, unfolding
from services.network.graph import (
    INF,
    Costs,
    Edges,
    Lazy,
    RoadGraph,
    SearchGraph,
    fixed_super_edges,
    kappa_cost,
    no_lazy,
    prepare,
    prepare_into,
)
from services.network.scratch import Scratch, ScratchPool
from services.sensing.gains import (
    Counted,
    Gains,
    TreeOut,
    TreeScratch,
    eval_path,
    eval_tree,
    mark,
    tree_scratch,
)

__all__ = [
    "Plans",
    "Problem",
    "problem",
    "Route",
    "Drive",
    "RouteScratch",
    "route_scratch",
    "plan_routes",
    "plan_one",
    "route_pair",
    "evaluate",
    "kappa_graph",
    "floor_metric",
]


GUIDED_PER_TREE = 32
"""About how many goal-directed searches (``astar.guided``) from a taxi to one POI cost as much as one
tree from the taxi to every POI in its reach; only speed depends on it. Measured on the heaviest load of
``bench/bench_epoch.py`` (processor time, one thread): on a uniform street grid that takes 53 minutes to
cross a tree costs 15-30 searches (there a search settles 400-800 nodes: many paths tie on cost), on
metro250k about 160 (a search settles about 90 nodes); no taxi there has more than 21 targets whose
fastest routes enter its counted cells."""


LANDMARK_TARGETS = 3
"""Up to how many POIs in its reach a taxi growing its own trees searches each POI goal-directed under each
kappa metric (``_kappa_paths_to``: the landmarks' bounds under the floor metric) instead of growing a
tree per kappa; only speed depends on it. On metro250k's platform load (processor time, one thread) a
taxi's searches took less time than its trees up to three POIs in reach, more from four on."""

OVERLAY_TAXIS = 8
"""From how many taxis growing their own kappa trees on the base normalization on, an epoch computes every
crossing super-edge's base kappa costs beforehand (``Overlay``; one pass over the crossing super-edges),
so that their trees compute only the super-edges entering their counted cells as they go; only
speed depends on it."""


class KappaGraph(NamedTuple):
    """The network as Algorithm 1's kernels take it: the edges, both search graphs with the travel time
    prepared for each, the edges that enter a cell (the only ones whose utility can be positive; split into
    the cells entered by an edge alone and the edges that enter several, for ``_umax_scan``), the
    bucket queue's geometry of any taxi's kappa metric (row q: kappa ``kappas[q]``; width: the cheapest
    super-edge when every edge is discounted fully), and the landmarks' bounds that guide the searches
    between two given nodes (``_guided_path``)."""

    ed: Edges
    fg: SearchGraph
    rg: SearchGraph
    time_fwd: Costs
    time_rev: Costs
    crossing: NDArray[np.int64]
    alone: NDArray[np.int64]  # the cells some edge enters alone (its utility: that cell's term), sorted
    multi: NDArray[np.int64]  # the edges that enter two cells or more
    fixed: NDArray[np.int64]  # (S,) forward: the cost of a super-edge that enters no cell, else -1
    cell_se_ptr: NDArray[np.int64]  # (C + 1,) CSR: per cell, the forward super-edges with an edge entering it
    cell_se: NDArray[np.int64]
    floor_width: NDArray[np.int64]
    floor_span: NDArray[np.int64]
    time_lm: NDArray[np.int64]  # (n, 2 L) the landmarks' table (``point_to_point.landmarks``)
    floor_lm: NDArray[np.int64]  # (n, 2 L) the same landmarks' under ``floor_metric`` ((0, 0): no kappa > 0)


class RouteScratch(NamedTuple):
    """What one thread's Algorithm 1 kernels work in: a forward and a reverse search workspace, a zero mask
    and an evaluation stamp over the gain table and the next stamp, a lazy metric's costs per edge and
    super-edge, the tree evaluation's scratch, and the cell sets of ``astar.guided``'s stop (per kept node
    of an in-tree, and of a taxi)."""

    forward: heaps.Workspace
    reverse: heaps.Workspace
    zmask: NDArray[np.bool_]
    stamp: NDArray[np.int64]
    next_stamp: NDArray[np.int64]  # (1,)
    edge_cost: NDArray[np.int64]  # (m,)
    se_cost: NDArray[np.int64]  # (S,) forward super-edges
    tree: TreeScratch
    cbits: NDArray[np.uint64]  # (K, astar.CLEAN_WORDS) an in-tree's path cells (astar.Guide)
    cdone: NDArray[np.int64]  # (K,) and the stamp of the in-tree they were written for
    cstack: NDArray[np.int64]  # (K,)
    zbits: NDArray[np.uint64]  # (astar.CLEAN_WORDS,) a taxi's counted cells


class Problem(NamedTuple):
    """One epoch's Algorithm 1: the gains, the taxis' counted pairs (row ``i``: taxi ``i``), their nodes, the
    POIs' nodes, the kappa family, the departure time and the reach in whole microseconds."""

    gn: Gains
    counted: Counted
    sources: NDArray[np.int64]
    targets: NDArray[np.int64]
    kappas: NDArray[np.float64]
    depart_s: float
    reach_us: int


class Best(NamedTuple):
    """The best route found so far per (taxi, POI): its kappa (index; -1 none), phi, gain, time and length;
    the fastest path's cost (``INF``: beyond the reach) and whether it enters a cell the taxi is counted
    in during the first slot. Routes are folded in kappa order, so ties stay with the smaller kappa."""

    kappa: NDArray[np.int64]
    phi: NDArray[np.float64]
    gain: NDArray[np.float64]
    time_s: NDArray[np.float64]
    length_m: NDArray[np.float64]
    d0_us: NDArray[np.int64]
    touched: NDArray[np.bool_]


def _best(f: int, p: int) -> Best:
    return Best(
        np.full((f, p), -1, dtype=np.int64),
        np.full((f, p), -np.inf),
        np.zeros((f, p)),
        np.full((f, p), np.nan),
        np.zeros((f, p)),
        np.full((f, p), INF, dtype=np.int64),
        np.zeros((f, p), dtype=np.bool_),
    )


class BaseKappa(NamedTuple):
    """What every taxi's kappa metrics share in one epoch: the largest entered utility with no cell zeroed
    and the edges that attain it, and the base kappa metrics (no cell zeroed) prepared for the reverse
    graph, for the POIs' in-trees (row q: kappa ``kappas[q]``; rows of kappa = 0 unused)."""

    umax: float
    top: NDArray[np.int64]
    edge: NDArray[np.int64]  # (kappas, m)
    se: NDArray[np.int64]  # (kappas, S reverse)
    width: NDArray[np.int64]  # (kappas,)
    span: NDArray[np.int64]


class Overlay(NamedTuple):
    """The super-edges' kappa costs of a taxi counted in no cell, with the base normalization (``base``, row
    q: kappa ``kappas[q]``; a super-edge that enters no cell: its travel time, as ``KappaGraph.fixed``),
    and one thread's copy of it (``own``) where a taxi's tree marks the super-edges entering its counted
    cells -1 (computed as the search reaches them) and restores them after. Shape (0, 0): none."""

    base: NDArray[np.int64]
    own: NDArray[np.int64]
    width: NDArray[np.int64]  # (kappas,) the bucket queue's: the cheapest super-edge in ``base``
    span: NDArray[np.int64]


def no_overlay() -> Overlay:
    """The ``Overlay`` of trees that compute every crossing super-edge's cost as they reach it."""
    empty = np.zeros((0, 0), dtype=np.int64)
    return Overlay(empty, empty, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


@compiled
def _base_kappa(net: KappaGraph, gains: Gains, kappas: NDArray[np.float64], in_trees: bool) -> BaseKappa:
    """The epoch's ``BaseKappa`` (its reverse metrics only when ``in_trees``). Only the edges that enter a
    cell have a utility; every other edge's kappa cost is its travel time."""
    ed = net.ed
    nc = net.crossing.shape[0]
    u = np.zeros(nc)
    umax = 0.0
    for r in range(nc):
        e = net.crossing[r]
        s = 0.0
        for j in range(ed.ec_ptr[e] + 1, ed.ec_ptr[e + 1]):
            s += gains.term[0, ed.ec_cell[j]]
        u[r] = s
        umax = max(umax, s)
    top = net.crossing[u == umax] if umax > 0.0 else np.zeros(0, dtype=np.int64)
    nk = kappas.shape[0] if in_trees else 0
    m = ed.time_s.shape[0] if in_trees else 0
    edge = np.zeros((nk, m), dtype=np.int64)
    se = np.zeros((nk, net.rg.se_tail.shape[0] if in_trees else 0), dtype=np.int64)
    width = np.ones(nk, dtype=np.int64)
    span = np.ones(nk, dtype=np.int64)
    for q in range(nk):
        if kappas[q] != 0.0 and umax > 0.0:
            edge[q] = ed.time_us
            for r in range(nc):
                e = net.crossing[r]
                edge[q, e] = kappa_cost(ed.time_s[e], u[r], umax, kappas[q])
            c = prepare_into(net.rg, edge[q], se[q])
            width[q] = c.width
            span[q] = c.span
    return BaseKappa(umax, top, edge, se, width, span)


@compiled
def _umax_scan(net: KappaGraph, gains: Gains, zmask: NDArray[np.bool_]) -> float:
    """The largest entered utility of the taxi whose zero mask is ``zmask``: over the edges that enter a
    cell, the first slot's terms of the cells the edge enters that the mask leaves open (``u_e`` of
    ``graph.Lazy``). An edge that enters one cell has that cell's term (0 when masked), so those edges
    are read once per cell (``net.alone``) and only the edges entering several are summed (``net.multi``):
    the same sums, in the same order, as over every edge."""
    ed = net.ed
    top = 0.0
    for c in net.alone:
        if not zmask[0, c]:
            top = max(top, gains.term[0, c])
    for e in net.multi:
        s = 0.0
        for j in range(ed.ec_ptr[e] + 1, ed.ec_ptr[e + 1]):
            c = ed.ec_cell[j]
            if not zmask[0, c]:
                s += gains.term[0, c]
        top = max(top, s)
    return top


@compiled
def _umax_of(net: KappaGraph, gains: Gains, zmask: NDArray[np.bool_], base: BaseKappa) -> float:
    """``_umax_scan`` of the taxi, the base's largest when one edge attaining it enters no cell the taxi
    is counted in (``base`` made from the same ``gains``)."""
    ed = net.ed
    for e in base.top:
        clear = True
        for j in range(ed.ec_ptr[e] + 1, ed.ec_ptr[e + 1]):
            if zmask[0, ed.ec_cell[j]]:
                clear = False
                break
        if clear:
            return base.umax
    return _umax_scan(net, gains, zmask)


@compiled_inline
def _own_metric(
    net: KappaGraph, scratch: RouteScratch, gains: Gains, kappa_row: int, kappa: float, umax: float
) -> tuple[Costs, Lazy]:
    """The kappa metric of the taxi whose zero mask ``scratch`` holds, computed as a search reaches it."""
    fixed, width, span = net.fixed, net.floor_width[kappa_row], net.floor_span[kappa_row]
    return _own_metric_over(net, scratch, gains, kappa_row, kappa, umax, fixed, width, span)


@compiled_inline
def _own_metric_over(
    net: KappaGraph,
    scratch: RouteScratch,
    gains: Gains,
    kappa_row: int,
    kappa: float,
    umax: float,
    fixed: NDArray[np.int64],
    width: int,
    span: int,
) -> tuple[Costs, Lazy]:
    """``_own_metric`` with the super-edges' costs known beforehand in ``fixed`` (-1: computed as the search
    reaches it) and the bucket queue's geometry: ``net.fixed`` and the floor's, or an ``Overlay``'s."""
    costs = Costs(scratch.edge_cost, scratch.se_cost, width, span)
    return costs, Lazy(True, kappa, umax, gains.term[0], scratch.zmask[0], fixed)


@compiled_inline
def _fold(best: Best, taxi: int, target: int, kappa_row: int, g: float, t: float, length: float) -> None:
    """Keep route (kappa ``kappa_row``, gain ``g``, time ``t``, length) for (``taxi``, POI ``target``) if its
    phi is larger than the best so far (phi 0 for a zero-length route)."""
    phi = g / t if t > 0 else 0.0
    if phi > best.phi[taxi, target]:
        best.phi[taxi, target] = phi
        best.kappa[taxi, target] = kappa_row
        best.gain[taxi, target] = g
        best.time_s[taxi, target] = t
        best.length_m[taxi, target] = length


@compiled
def _eval_walk(
    edges: Edges,
    gains: Gains,
    scratch: RouteScratch,
    succ: NDArray[np.int64],
    start: int,
    root: int,
    depart_s: float,
) -> tuple[float, float, float, int, bool]:
    """``gains.eval_path`` along the in-tree path from ``start`` to ``root`` (same operations, same order),
    and whether the path enters a cell the taxi is counted in during the first slot (its zero mask's row 0):
    only on such an edge can the taxi's own kappa metric exceed the base one."""
    term, zmask, stamp = gains.term, scratch.zmask, scratch.stamp
    shift_s, interval_s, k0 = gains.shift_s, gains.interval_s, gains.k0
    time_s, length_m, head = edges.time_s, edges.length_m, edges.head
    ec_ptr, ec_cell, ec_frac = edges.ec_ptr, edges.ec_cell, edges.ec_frac
    n_slots = term.shape[0]
    sid = scratch.next_stamp[0]
    scratch.next_stamp[0] = sid + 1
    t = depart_s
    g = 0.0
    length = 0.0
    max_slot = 0
    touched = False
    x = start
    while x != root:  # the records' arrays taken out above: a read in the loop counts a reference
        e = succ[x]
        te = time_s[e]
        first = ec_ptr[e]
        for j in range(first, ec_ptr[e + 1]):
            c = ec_cell[j]
            if j > first and zmask[0, c]:
                touched = True
            slot = int(np.floor((t + ec_frac[j] * te + shift_s) / interval_s)) - k0
            if slot > max_slot:
                max_slot = slot
            if slot >= n_slots:
                continue
            if stamp[slot, c] == sid:
                continue
            stamp[slot, c] = sid
            if not zmask[slot, c]:
                g += term[slot, c]
        t += te
        length += length_m[e]
        x = head[e]
    return g, t - depart_s, length, max_slot, touched


@compiled
def _fastest_to(net: KappaGraph, problem: Problem, scratch: RouteScratch, best: Best, target: int) -> int:
    """POI ``target``'s in-tree under the travel time, bounded by the reach and stopped once every taxi is
    settled: every taxi's fastest route to it, evaluated and folded (kappa 0), with its cost and whether it
    enters a cell the taxi is counted in. Returns the largest slot reached."""
    ed = net.ed
    f = problem.sources.shape[0]
    root = problem.targets[target]
    ws = scratch.reverse
    dijkstra.run(net.rg, ed, net.time_rev, root, problem.reach_us, problem.sources, ws)
    reached = np.empty(f, dtype=np.bool_)
    unfolding.unfold_many(net.rg, ed, net.time_rev, problem.reach_us, problem.sources, ws, reached)
    label = np.empty((3, f), dtype=np.int64)
    unfolding.labels(net.rg, ed, net.time_rev, problem.reach_us, problem.sources, ws, label)
    max_slot = 0
    for a in range(f):
        if not reached[a]:
            continue
        mark(scratch.zmask, problem.counted, a, True)
        g, t, length, ms, touch = _eval_walk(
            ed, problem.gn, scratch, ws.pred, problem.sources[a], root, problem.depart_s
        )
        mark(scratch.zmask, problem.counted, a, False)
        best.d0_us[a, target] = label[0, a]
        best.touched[a, target] = touch
        _fold(best, a, target, 0, g, t, length)
        max_slot = max(max_slot, ms)
    return max_slot


@compiled
def _zbits(counted: Counted, taxi: int, out: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """The cells ``taxi`` is counted in during the first slot, as a ``astar.cell_bit`` set in ``out``."""
    out[:] = 0
    for p in range(counted.ptr[taxi], counted.ptr[taxi + 1]):
        if counted.slot[p] == 0:
            astar.cell_bit(out, counted.cell[p])
    return out


@compiled_inline
def _eval_stamped(
    road_edges: Edges, gains: Gains, scratch: RouteScratch, edges: NDArray[np.int64], depart_s: float
) -> tuple[float, float, float, int]:
    """``eval_path`` of ``edges`` under the zero mask ``scratch`` holds, on the scratch's next evaluation
    stamp: gain, travel time, length, largest slot reached."""
    sid = scratch.next_stamp[0]
    scratch.next_stamp[0] = sid + 1
    g, _gq, t, length, ms = eval_path(road_edges, gains, scratch.zmask, scratch.stamp, sid, edges, depart_s)
    return g, t, length, ms


@compiled
def _own_route(
    net: KappaGraph,
    problem: Problem,
    scratch: RouteScratch,
    base_q: Costs,
    guide: astar.Guide,
    lazy: Lazy,
    mine: Costs,
    drive: Drive,
) -> tuple[float, float, float, int]:
    """Taxi ``drive.i``'s route under its own costs ``mine`` (``lazy``) to ``drive.target``, searched
    goal-directed by the in-tree (``base_q``, grown in ``scratch.reverse`` to ``drive.limit``) that
    ``guide`` reads, and evaluated: gain, time, length, largest slot. Where the search stops at a node whose
    in-tree path enters none of the taxi's counted cells, the route is the path to it followed by that in-tree
    path (``astar.guided``)."""
    ed = net.ed
    meet = astar.guided(net.fg, ed, mine, drive.source, drive.target, scratch.forward, guide, lazy)
    if meet < 0:
        unfolding.unfold(net.fg, ed, mine, INF, drive.target, scratch.forward)
        edges = unfolding.path_to(ed, 1, scratch.forward.pred, drive.source, drive.target)
    else:
        x = net.fg.kept[meet]
        unfolding.unfold(net.fg, ed, mine, INF, x, scratch.forward)
        head = unfolding.path_to(ed, 1, scratch.forward.pred, drive.source, x)
        unfolding.unfold(net.rg, ed, base_q, drive.limit, x, scratch.reverse)
        edges = np.concatenate((head, unfolding.walk(ed, scratch.reverse.pred, x, drive.target)))
    return _eval_stamped(ed, problem.gn, scratch, edges, problem.depart_s)


@compiled
def _kappas_to(
    net: KappaGraph,
    problem: Problem,
    base: BaseKappa,
    own: NDArray[np.bool_],
    scratch: RouteScratch,
    best: Best,
    target: int,
) -> tuple[int, int]:
    """POI ``target``'s in-tree under each base kappa metric, grown to the farthest fastest route of a taxi in
    reach (not ``own``): each such taxi's route in it is its own unless it enters a cell the taxi is
    counted in; then the taxi is searched again under its own costs, goal-directed by the in-tree's labels
    (``astar.tree_guide``: they never exceed the taxi's own), and stopped where the in-tree's path enters
    none of its counted cells (``_own_route``). Folded in kappa order. Returns the largest slot reached and
    the number of goal-directed searches."""
    ed = net.ed
    scratch = scratch
    root = problem.targets[target]
    limit = -1
    n = 0
    who = np.empty(problem.sources.shape[0], dtype=np.int64)
    for a in range(problem.sources.shape[0]):
        if not own[a] and best.d0_us[a, target] < INF:
            who[n] = a
            n += 1
            limit = max(limit, best.d0_us[a, target])
    if n == 0:
        return 0, 0
    who = who[:n]
    nodes = problem.sources[who]
    reached = np.empty(n, dtype=np.bool_)
    max_slot = 0
    guided = 0
    for q in range(problem.kappas.shape[0]):
        kappa = problem.kappas[q]
        if kappa == 0.0 or base.umax <= 0.0:
            continue
        costs = Costs(base.edge[q], base.se[q], base.width[q], base.span[q])
        dijkstra.run(net.rg, ed, costs, root, limit, np.empty(0, dtype=np.int64), scratch.reverse)
        if not unfolding.unfold_many(net.rg, ed, costs, limit, nodes, scratch.reverse, reached):
            raise AssertionError("a discounted route costs more than the fastest path's time")
        stamp = scratch.next_stamp[0]  # the in-tree's path cells, written as guided searches ask
        scratch.next_stamp[0] = stamp + 1
        cells = (scratch.cbits, scratch.cdone, scratch.cstack)
        for r in range(n):
            a = who[r]
            mark(scratch.zmask, problem.counted, a, True)
            g, t, length, ms, touch = _eval_walk(
                ed, problem.gn, scratch, scratch.reverse.pred, nodes[r], root, problem.depart_s
            )
            if touch:
                zbits = _zbits(problem.counted, a, scratch.zbits)
                gd = astar.tree_guide(net.rg, scratch.reverse, limit, cells, stamp, zbits)
                mine, lazy = _own_metric(net, scratch, problem.gn, q, kappa, base.umax)
                leg = Drive(a, nodes[r], root, limit)
                g, t, length, ms = _own_route(net, problem, scratch, costs, gd, lazy, mine, leg)
                guided += 1
            mark(scratch.zmask, problem.counted, a, False)
            _fold(best, a, target, q, g, t, length)
            max_slot = max(max_slot, ms)
    return max_slot, guided


@compiled
def _from_taxi(
    net: KappaGraph,
    problem: Problem,
    base: BaseKappa,
    scratch: RouteScratch,
    best: Best,
    taxi: int,
    fastest: bool,
    overlay: Overlay,
    few: int,
) -> tuple[int, int]:
    """Taxi ``taxi``'s trees: under the travel time (when ``fastest``: bounded by the reach, every POI a
    target) and under each of its kappa metrics, bounded by its farthest fastest route to a POI in reach
    with those POIs as targets; evaluated along the tree and folded in kappa order. Where the taxi's
    normalization is the base's, its kappa metrics are read from ``overlay`` (when it holds one) but on the
    super-edges entering a cell it is counted in. Returns the largest slot reached and the number of trees
    grown."""
    ed = net.ed
    src = problem.sources[taxi]
    scratch = scratch
    ws = scratch.forward
    p = problem.targets.shape[0]
    g = np.zeros(p)
    t = np.zeros(p)
    length = np.zeros(p)
    out = TreeOut(g, t, length)
    max_slot = 0
    grown = 0
    mark(scratch.zmask, problem.counted, taxi, True)
    if fastest:
        dijkstra.run(net.fg, ed, net.time_fwd, src, problem.reach_us, problem.targets, ws)
        grown += 1
        reached = np.empty(p, dtype=np.bool_)
        unfolding.unfold_many(net.fg, ed, net.time_fwd, problem.reach_us, problem.targets, ws, reached)
        label = np.empty((3, p), dtype=np.int64)
        unfolding.labels(net.fg, ed, net.time_fwd, problem.reach_us, problem.targets, ws, label)
        near = np.flatnonzero(reached)
        ms = eval_tree(
            ed,
            problem.gn,
            scratch.zmask,
            ws.pred,
            src,
            problem.targets[near],
            problem.depart_s,
            scratch.tree,
            out,
        )
        max_slot = max(max_slot, ms)
        for r in range(near.shape[0]):
            j = near[r]
            best.d0_us[taxi, j] = label[0, j]
            _fold(best, taxi, j, 0, g[r], t[r], length[r])
    ms, n = _taxi_kappa_trees(net, problem, base, scratch, best, taxi, overlay, out, few)
    mark(scratch.zmask, problem.counted, taxi, False)
    return max(max_slot, ms), grown + n


@compiled
def _taxi_kappa_trees(
    net: KappaGraph,
    problem: Problem,
    base: BaseKappa,
    scratch: RouteScratch,
    best: Best,
    taxi: int,
    overlay: Overlay,
    out: TreeOut,
    few: int,
) -> tuple[int, int]:
    """``_from_taxi``'s kappa > 0 trees (the taxi's zero mask set in ``scratch``, its fastest routes in
    ``best``; ``out``: room for one route per POI): the largest slot reached and the number grown. A taxi
    with at most ``few`` POIs in reach searches each of them goal-directed instead (``_kappa_paths_to``; each
    search counted as one grown)."""
    ed = net.ed
    src = problem.sources[taxi]
    ws = scratch.forward
    g, t, length = out.gain, out.time_s, out.length_m
    max_slot = 0
    grown = 0
    near = np.flatnonzero(best.d0_us[taxi] < INF)
    if near.shape[0] > 0 and base.umax > 0.0:
        limit = best.d0_us[taxi][near].max()
        umax = _umax_of(net, problem.gn, scratch.zmask, base)
        nodes = problem.targets[near]
        reached = np.empty(near.shape[0], dtype=np.bool_)
        over = overlay.own.shape[0] > 0 and umax == base.umax
        if over:
            _overlay_taxi(net, problem.counted, taxi, overlay, True)
        for q in range(problem.kappas.shape[0]):
            kappa = problem.kappas[q]
            if kappa == 0.0 or umax <= 0.0:
                continue
            if over:
                w, span = overlay.width[q], overlay.span[q]
                costs, lazy = _own_metric_over(
                    net, scratch, problem.gn, q, kappa, umax, overlay.own[q], w, span
                )
            else:
                costs, lazy = _own_metric(net, scratch, problem.gn, q, kappa, umax)
            if near.shape[0] <= few:
                ms = _kappa_paths_to(
                    net, problem, scratch, costs, lazy, Drive(taxi, src, -1, limit), nodes, out
                )
                grown += near.shape[0]
                max_slot = max(max_slot, ms)
                for r in range(near.shape[0]):
                    _fold(best, taxi, near[r], q, g[r], t[r], length[r])
                continue
            dijkstra.grow(net.fg, ed, costs, src, limit, nodes, ws, lazy)
            grown += 1
            if not unfolding.unfold_many(net.fg, ed, costs, limit, nodes, ws, reached):
                raise AssertionError("a discounted route costs more than the fastest path's time")
            ms = eval_tree(
                ed, problem.gn, scratch.zmask, ws.pred, src, nodes, problem.depart_s, scratch.tree, out
            )
            max_slot = max(max_slot, ms)
            for r in range(near.shape[0]):
                _fold(best, taxi, near[r], q, g[r], t[r], length[r])
        if over:
            _overlay_taxi(net, problem.counted, taxi, overlay, False)
    return max_slot, grown


@compiled
def _kappa_paths_to(
    net: KappaGraph,
    problem: Problem,
    scratch: RouteScratch,
    costs: Costs,
    lazy: Lazy,
    drive: Drive,
    nodes: NDArray[np.int64],
    out: TreeOut,
) -> int:
    """The canonical paths from ``drive.source`` to each of ``nodes`` under ``costs`` (``lazy``), one
    goal-directed search each (``_guided_path``, the landmarks' bounds under the floor metric), evaluated
    into ``out`` as ``eval_tree`` would; the largest slot reached."""
    max_slot = 0
    for r in range(nodes.shape[0]):
        leg = Drive(drive.i, drive.source, nodes[r], drive.limit)
        edges = _guided_path(net, scratch.forward, costs, lazy, leg, net.floor_lm)
        if scratch.forward.info[1] == -1:
            raise AssertionError("a discounted route costs more than the fastest path's time")
        g, t, length, ms = _eval_stamped(net.ed, problem.gn, scratch, edges, problem.depart_s)
        out.gain[r], out.time_s[r], out.length_m[r] = g, t, length
        max_slot = max(max_slot, ms)
    return max_slot


@compiled
def _overlay_base(net: KappaGraph, gains: Gains, kappas: NDArray[np.float64], umax: float) -> Overlay:
    """The ``Overlay`` (``own`` its ``base``) of a taxi counted in no cell whose largest entered utility is
    ``umax``: every crossing super-edge's cost under each kappa metric (``dijkstra.crossing_cost``'s sums,
    the same operations as a lazy search makes: the same integers; written out here so that each edge's
    utility is summed once for every kappa, not once per kappa), every other super-edge's travel time. A
    taxi counted in cells costs as much or more on every super-edge (it sums fewer non-negative terms into
    an edge's utility), so the cheapest super-edge bounds its metric's from below, and its travel time any
    super-edge's cost from above."""
    nk, n_se = kappas.shape[0], net.fixed.shape[0]
    out = np.empty((nk, n_se), dtype=np.int64)
    width = np.ones(nk, dtype=np.int64)
    span = np.ones(nk, dtype=np.int64)
    hi = max(1, net.time_fwd.se.max()) if n_se > 0 else 1
    term, fixed = gains.term[0], net.fixed
    se_ptr, se_edges = net.fg.se_ptr, net.fg.se_edges  # out of the records once, as the searches take them
    ec_ptr, ec_cell, time_s = net.ed.ec_ptr, net.ed.ec_cell, net.ed.time_s
    live = np.array([kappas[q] != 0.0 and umax > 0.0 for q in range(nk)])
    for q in range(nk):
        out[q] = fixed
    for s in range(n_se):
        if fixed[s] >= 0:
            continue
        for q in range(nk):
            if live[q]:
                out[q, s] = 0
        for p in range(se_ptr[s], se_ptr[s + 1]):  # dijkstra.crossing_cost's sums, no cell zeroed
            e = se_edges[p]
            u = 0.0
            for j in range(ec_ptr[e] + 1, ec_ptr[e + 1]):
                u += term[ec_cell[j]]
            for q in range(nk):
                if live[q]:
                    out[q, s] += kappa_cost(time_s[e], u, umax, kappas[q])
    for q in range(nk):
        width[q] = max(1, out[q].min()) if n_se > 0 else 1
        span[q] = hi // width[q] + 2
    return Overlay(out, out, width, span)


@compiled
def _overlay_taxi(net: KappaGraph, counted: Counted, taxi: int, overlay: Overlay, on: bool) -> None:
    """In ``overlay.own``, set the super-edges with an edge entering a cell ``taxi`` is counted in during the
    first slot to -1 (``on``), or restore them from ``overlay.base``."""
    for p in range(counted.ptr[taxi], counted.ptr[taxi + 1]):
        if counted.slot[p] != 0:
            continue
        c = counted.cell[p]
        for r in range(net.cell_se_ptr[c], net.cell_se_ptr[c + 1]):
            se = net.cell_se[r]
            for q in range(overlay.own.shape[0]):
                overlay.own[q, se] = -1 if on else overlay.base[q, se]


def _alone_and_multi(
    edges: Edges, crossing: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``KappaGraph.alone`` and ``multi``: the cells entered by some edge of ``crossing`` alone, and the
    edges of ``crossing`` that enter several cells."""
    entered = edges.ec_ptr[crossing + 1] - edges.ec_ptr[crossing] - 1
    alone = np.unique(edges.ec_cell[edges.ec_ptr[crossing[entered == 1]] + 1])
    return alone.astype(np.int64), crossing[entered > 1].astype(np.int64)


def _cell_super_edges(
    graph: SearchGraph, edges: Edges, n_cells: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``KappaGraph.cell_se_ptr`` and ``cell_se``: per cell, the super-edges of ``graph`` with an edge that
    enters it (a cell of the edge's but its first), in super-edge order."""
    se = np.repeat(np.arange(graph.se_ptr.shape[0] - 1, dtype=np.int64), np.diff(graph.se_ptr))
    first = edges.ec_ptr[graph.se_edges] + 1  # per (super-edge, edge): its entered cells' range
    entered = edges.ec_ptr[graph.se_edges + 1] - first
    pos = np.repeat(first - np.cumsum(entered) + entered, entered) + np.arange(int(entered.sum()))
    cells = edges.ec_cell[pos]
    order = np.argsort(cells, kind="stable")
    ptr = np.zeros(n_cells + 1, dtype=np.int64)
    np.cumsum(np.bincount(cells, minlength=n_cells), out=ptr[1:])
    return ptr, np.repeat(se, entered)[order]


@compiled
def _own_normalized(
    net: KappaGraph, problem: Problem, base: BaseKappa, scratch: RouteScratch
) -> NDArray[np.bool_]:
    """Per taxi: its largest utility is not the base's (its kappa metrics are not the base's raised)."""
    f = problem.sources.shape[0]
    out = np.zeros(f, dtype=np.bool_)
    for i in range(f):
        mark(scratch.zmask, problem.counted, i, True)
        out[i] = _umax_of(net, problem.gn, scratch.zmask, base) != base.umax
        mark(scratch.zmask, problem.counted, i, False)
    return out


@dataclass(frozen=True, slots=True, eq=False)
class Plans:
    """Algorithm 1 from each of F taxis to each of P targets: the chosen kappa (index into ``kappas``; -1:
    the target is beyond the taxi's reach), gain, travel time (NaN beyond the reach) and length of the
    route, and the fastest path's cost in whole microseconds, as (F, P) arrays; the largest slot any
    route reached."""

    kappas: NDArray[np.float64]
    kappa_index: NDArray[np.int64]
    gain: NDArray[np.float64]
    time_s: NDArray[np.float64]
    length_m: NDArray[np.float64]
    d0_us: NDArray[np.int64]
    max_slot: int
    in_trees: int = 0  # searches from the targets (one per kappa and target)
    guided_searches: int = 0  # goal-directed searches of taxis whose in-tree route enters a counted cell
    taxi_searches: int = 0  # searches from the taxis, per taxi and kappa not served by the in-trees: a tree,
    # or one goal-directed search per POI in reach (at most LANDMARK_TARGETS)

    @property
    def phi(self) -> NDArray[np.float64]:
        """phi = gain / time (Eq. 12); 0 for a zero-length route or a pair beyond the reach."""
        t = self.time_s
        return np.divide(self.gain, t, out=np.zeros_like(self.gain), where=t > 0)

    @property
    def candidate(self) -> NDArray[np.bool_]:
        """The (taxi, target) pairs within the reach."""
        return self.kappa_index >= 0


def problem(
    gains: Gains,
    counted: Counted,
    sources: NDArray[np.int64],
    targets: NDArray[np.int64],
    kappas: Sequence[float],
    depart_s: float,
    reach_us: int = INF,
) -> Problem:
    """Algorithm 1 from every source (taxi ``i``'s counted pairs in row ``i`` of ``counted``) to every target
    within its reach (the fastest path takes at most ``reach_us``; ``INF``: every target), departing at
    ``depart_s`` on the gains ``gains``, as the kernels take it."""
    return Problem(
        gains,
        counted,
        np.asarray(sources, np.int64),
        np.asarray(targets, np.int64),
        np.asarray(kappas, dtype=np.float64),
        depart_s,
        int(reach_us),
    )


def plan_routes(
    graph: RoadGraph,
    problem: Problem,
    workers: int,
    pool: ScratchPool,
    *,
    fastest_from_targets: bool | None = None,
) -> Plans:
    """Algorithm 1 for ``problem`` (made by :func:`problem`): the best route from every source to every target
    within its reach, on ``workers`` threads.

    When there are fewer than half as many targets as sources (``fastest_from_targets`` forces the choice),
    the routes come from one in-tree per target and kappa under the metric every taxi shares (the travel
    time; the base kappa metric, no cell zeroed); a taxi whose in-tree route enters a cell it is counted in
    is searched again to that target under its own costs, goal-directed by the in-tree, and a taxi whose
    normalization is its own, or whose fastest routes enter its counted cells on the way to more than
    ``GUIDED_PER_TREE`` targets, grows its kappa > 0 trees itself; when fewer than twice as many taxis as
    targets are left to read them, no kappa > 0 in-trees are grown. The routes are the same either way:
    docs/DISPATCH.md proves it and the tests check it.

    Raises
    ------
    ValueError
        When a target cannot be reached from a source and there is no reach.
    """
    gn, kap = problem.gn, problem.kappas
    f, p = len(problem.sources), len(problem.targets)
    kt = kappa_graph(graph, tuple(kap.tolist()))
    best = _best(f, p)
    from_roots = (0 < 2 * p < f) if fastest_from_targets is None else (fastest_from_targets and p > 0)
    base = _base_kappa(kt, gn, kap, from_roots)
    own = np.zeros(f, dtype=np.bool_)
    in_trees = guided = 0
    slots: list[int] = []
    if from_roots:
        slots, own, in_trees, guided = _in_trees(kt, problem, base, best, workers, pool)

    rows = np.flatnonzero(own).tolist() if from_roots else list(range(f))
    over_base = (
        _overlay_base(kt, gn, kap, base.umax) if len(rows) >= OVERLAY_TAXIS and base.umax > 0.0 else None
    )
    copies: dict[int, Overlay] = {}  # per thread, for this call only

    def thread_overlay() -> Overlay:
        if over_base is None:
            return no_overlay()
        got = copies.get(threading.get_ident())
        if got is None:  # each thread's taxis restore what they mark, so one copy serves them all
            got = copies[threading.get_ident()] = over_base._replace(own=over_base.base.copy())
        return got

    def taxis(rows: Sequence[int]) -> list[tuple[int, int]]:
        with pool.take() as thread_scratch:
            scratch = route_scratch(thread_scratch, gn)
            overlay = thread_overlay()
            return [
                _from_taxi(kt, problem, base, scratch, best, i, not from_roots, overlay, LANDMARK_TARGETS)
                for i in rows
            ]

    done = parallel_map(taxis, rows, workers)
    slots += [ms for ms, _ in done]
    if problem.reach_us >= INF and f and p and (best.d0_us >= INF).any():
        a, j = np.argwhere(best.d0_us >= INF)[0]
        raise ValueError(
            f"node {int(problem.targets[j])} cannot be reached from node {int(problem.sources[a])}"
        )
    return Plans(
        kap,
        best.kappa,
        best.gain,
        best.time_s,
        best.length_m,
        best.d0_us,
        max(slots, default=0),
        in_trees,
        guided,
        sum(n for _, n in done),
    )


def _in_trees(
    net: KappaGraph, problem: Problem, base: BaseKappa, best: Best, workers: int, pool: ScratchPool
) -> tuple[list[int], NDArray[np.bool_], int, int]:
    """``plan_routes``'s routes from the targets' in-trees (into ``best``): one fastest in-tree per target,
    then the kappa > 0 in-trees when they serve enough taxis. Returns the largest slots reached, which taxis
    must still grow their own trees, and the numbers of in-trees grown and of goal-directed searches."""
    gn, kap = problem.gn, problem.kappas
    f, p = len(problem.sources), len(problem.targets)
    guided = 0

    def fastest(js: Sequence[int]) -> list[int]:
        with pool.take() as thread_scratch:
            scratch = route_scratch(thread_scratch, gn)
            return [_fastest_to(net, problem, scratch, best, j) for j in js]

    slots: list[int] = parallel_map(fastest, range(p), workers)
    in_trees = p
    with pool.take() as thread_scratch:
        own = _own_normalized(net, problem, base, route_scratch(thread_scratch, gn))
    # A taxi whose fastest routes enter its counted cells on the way to many targets will likely need
    # as many goal-directed searches per kappa: past GUIDED_PER_TREE of them, one tree of its own per
    # kappa is cheaper (speed only: both give the canonical routes).
    own |= best.touched.sum(axis=1) > GUIDED_PER_TREE
    if 2 * p < f - int(own.sum()) and base.umax > 0.0:

        def kappa_trees(js: Sequence[int]) -> list[tuple[int, int]]:
            with pool.take() as thread_scratch:
                scratch = route_scratch(thread_scratch, gn)
                return [_kappas_to(net, problem, base, own, scratch, best, j) for j in js]

        done = parallel_map(kappa_trees, range(p), workers)
        slots += [ms for ms, _ in done]
        guided = sum(n for _, n in done)
        in_trees += p * int(np.count_nonzero(kap != 0.0))
    else:
        # The kappa > 0 in-trees pay only while they serve twice as many taxis as there are targets,
        # as for kappa = 0 (speed only: both give the canonical routes).
        own[:] = True
    return slots, own, in_trees, guided


def route_scratch(thread_scratch: Scratch, gains: Gains) -> RouteScratch:
    """The thread's scratch for Algorithm 1 with tables shaped like ``gains``: its two search workspaces and
    arrays kept in its ``extra`` (made on first need)."""
    key = ("algorithm1", gains.term.shape)
    got = thread_scratch.extra.get(key)
    if not isinstance(got, RouteScratch):
        graph = thread_scratch.graph
        shape = gains.term.shape
        k = int(graph.reverse.kept.shape[0])
        got = thread_scratch.extra[key] = RouteScratch(
            thread_scratch.forward,
            thread_scratch.reverse,
            np.zeros(shape, np.bool_),
            np.zeros(shape, np.int64),
            np.ones(1, np.int64),
            np.zeros(graph.n_edges, np.int64),
            np.zeros(graph.forward.se_tail.shape[0], np.int64),
            tree_scratch(graph.n_nodes, shape),
            np.zeros((k, astar.CLEAN_WORDS), np.uint64),
            np.zeros(k, np.int64),
            np.zeros(k, np.int64),
            np.zeros(astar.CLEAN_WORDS, np.uint64),
        )
    return got


@compiled
def _floor(
    forward: SearchGraph, edges: Edges, time_fwd: Costs, kappas: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per kappa, the bucket width and span of any taxi's kappa metric: the cheapest super-edge with every
    edge discounted fully (``kappa_cost`` never goes lower), and the travel time's dearest over it."""
    nk = kappas.shape[0]
    width = np.ones(nk, dtype=np.int64)
    span = np.ones(nk, dtype=np.int64)
    hi = 1
    for s in range(time_fwd.se.shape[0]):
        hi = max(hi, time_fwd.se[s])
    for q in range(nk):
        lo = INF
        for s in range(forward.se_tail.shape[0]):
            c = 0
            for r in range(forward.se_ptr[s], forward.se_ptr[s + 1]):
                c += kappa_cost(edges.time_s[forward.se_edges[r]], 1.0, 1.0, kappas[q])
            lo = min(lo, c)
        width[q] = max(lo if lo < INF else 1, 1)
        span[q] = hi // width[q] + 2
    return width, span


@compiled
def floor_metric(edges: Edges, kappa: float) -> NDArray[np.int64]:
    """Per edge, the least it costs under any taxi's kappa metric of a family whose largest kappa is
    ``kappa``: an edge that enters a cell discounted fully (``kappa_cost(t, 1, 1, kappa)``), any other its
    travel time (``kappa_cost`` is monotone in both, so no metric of the family costs less anywhere)."""
    m = edges.time_s.shape[0]
    out = np.empty(m, dtype=np.int64)
    for e in range(m):
        crossing = edges.ec_ptr[e + 1] - edges.ec_ptr[e] > 1
        out[e] = kappa_cost(edges.time_s[e], 1.0 if crossing else 0.0, 1.0, kappa)
    return out


def _floor_landmarks(graph: RoadGraph, kappa: float) -> NDArray[np.int64]:
    """The landmarks' table under ``floor_metric`` (``point_to_point.landmark_table``): lower bounds on every
    kappa metric of the family, a potential for ``astar.guided`` (none when no kappa is positive)."""
    if kappa <= 0.0:
        return np.zeros((0, 0), dtype=np.int64)
    floor = floor_metric(graph.edges, kappa)
    return point_to_point.landmark_table(
        graph,
        point_to_point.landmark_nodes(graph),
        prepare(graph.forward, floor),
        prepare(graph.reverse, floor),
        default_workers(),
    )


_kits: weakref.WeakKeyDictionary[RoadGraph, dict[tuple[float, ...], KappaGraph]] = weakref.WeakKeyDictionary()
_kits_lock = threading.Lock()


def kappa_graph(graph: RoadGraph, kappas: tuple[float, ...]) -> KappaGraph:
    """The ``KappaGraph`` of ``graph`` for the kappa family ``kappas`` (built once per graph and family)."""
    with _kits_lock:
        per = _kits.setdefault(graph, {})
        got = per.get(kappas)
        if got is None:
            ed = graph.edges
            width, span = _floor(graph.forward, ed, graph.time_forward, np.asarray(kappas, dtype=np.float64))
            got = per[kappas] = KappaGraph(
                ed,
                graph.forward,
                graph.reverse,
                graph.time_forward,
                graph.time_reverse,
                graph.crossing,
                *_alone_and_multi(ed, graph.crossing),
                fixed_super_edges(graph.forward, ed, graph.time_forward),
                *_cell_super_edges(graph.forward, ed, int(graph.n_cells)),
                width,
                span,
                point_to_point.landmarks(graph),
                _floor_landmarks(graph, max(kappas, default=0.0)),
            )
        return got


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


class Drive(NamedTuple):
    """One taxi's drive to one target: the taxi's row ``i`` of the counted pairs, its node, the target, and
    a bound on the cost of any of its routes there (the fastest path's travel time, or more)."""

    i: int
    source: int
    target: int
    limit: int


@compiled
def _path(
    net: KappaGraph, workspace: heaps.Workspace, costs: Costs, lazy: Lazy, drive: Drive
) -> NDArray[np.int64]:
    """The canonical path of ``drive`` under ``costs`` (computed as the search goes when ``lazy.on``)
    (empty and ``workspace.info[1] == -1`` when it is not reached within the leg's limit)."""
    tgt = np.empty(1, dtype=np.int64)
    tgt[0] = drive.target
    dijkstra.grow(net.fg, net.ed, costs, drive.source, drive.limit, tgt, workspace, lazy)
    if not unfolding.unfold(net.fg, net.ed, costs, drive.limit, drive.target, workspace):
        workspace.info[1] = -1
        return np.empty(0, dtype=np.int64)
    return unfolding.path_to(net.ed, 1, workspace.pred, drive.source, drive.target)


@compiled
def _guided_path(
    net: KappaGraph, workspace: heaps.Workspace, costs: Costs, lazy: Lazy, drive: Drive, lm: NDArray[np.int64]
) -> NDArray[np.int64]:
    """``_path``, searched goal-directed by the bounds of the landmarks' table ``lm`` (``astar.guided``; shape
    (0, 0): plainly): the same canonical path. ``lm`` must bound the metric ``costs`` from below: the travel
    time's table (``time_lm``) for the travel time, ``floor_lm`` for any kappa metric of the family."""
    if lm.shape[0] == 0:
        return _path(net, workspace, costs, lazy, drive)
    guide = astar.potential_guide(np.zeros((3, 0), dtype=np.int64), lm)
    astar.guided(net.fg, net.ed, costs, drive.source, drive.target, workspace, guide, lazy)
    if not unfolding.unfold(net.fg, net.ed, costs, drive.limit, drive.target, workspace):
        workspace.info[1] = -1
        return np.empty(0, dtype=np.int64)
    return unfolding.path_to(net.ed, 1, workspace.pred, drive.source, drive.target)


@compiled
def _kappa_path(
    net: KappaGraph,
    scratch: RouteScratch,
    gains: Gains,
    counted: Counted,
    drive: Drive,
    kappa_row: int,
    kappa: float,
) -> NDArray[np.int64]:
    """Taxi ``drive.i``'s canonical path under its kappa ``kappa_row`` metric (the fastest when it has no
    utility)."""
    mark(scratch.zmask, counted, drive.i, True)
    umax = _umax_scan(net, gains, scratch.zmask) if kappa != 0.0 else 0.0
    if kappa == 0.0 or umax <= 0.0:
        route = _guided_path(net, scratch.forward, net.time_fwd, no_lazy(), drive, net.time_lm)
    else:
        costs, lazy = _own_metric(net, scratch, gains, kappa_row, kappa, umax)
        route = _guided_path(net, scratch.forward, costs, lazy, drive, net.floor_lm)
    mark(scratch.zmask, counted, drive.i, False)
    return route


def route_pair(
    graph: RoadGraph,
    gains: Gains,
    counted: Counted,
    drive: Drive,
    kappas: Sequence[float],
    kappa_row: int,
    thread_scratch: Scratch,
) -> NDArray[np.int64]:
    """Taxi ``drive.i``'s kappa ``kappas[q]`` route to ``drive.target``: the canonical path its trees in
    ``plan_routes`` held (found again rather than kept: a tree per taxi and kappa is too much memory at
    metropolitan scale).

    Raises
    ------
    ValueError
        When the target cannot be reached within the leg's limit.
    """
    kt = kappa_graph(graph, tuple(float(k) for k in kappas))
    scratch = route_scratch(thread_scratch, gains)
    route = _kappa_path(kt, scratch, gains, counted, drive, kappa_row, float(kappas[kappa_row]))
    if scratch.forward.info[1] == -1:
        raise ValueError(f"node {drive.target} cannot be reached from node {drive.source}")
    return route


@compiled
def _evaluate(
    road_edges: Edges,
    gains: Gains,
    scratch: RouteScratch,
    counted: Counted,
    taxi: int,
    edges: NDArray[np.int64],
    depart_s: float,
) -> tuple[float, float, float, int]:
    """``gains.eval_path`` of ``taxi``'s path: gain, time, length, largest slot reached."""
    mark(scratch.zmask, counted, taxi, True)
    g, t, length, ms = _eval_stamped(road_edges, gains, scratch, edges, depart_s)
    mark(scratch.zmask, counted, taxi, False)
    return g, t, length, ms


def evaluate(
    graph: RoadGraph,
    gains: Gains,
    counted: Counted,
    taxi: int,
    edges: NDArray[np.int64],
    depart_s: float,
    thread_scratch: Scratch,
) -> tuple[float, float, float, int]:
    """Taxi ``taxi``'s path evaluated against ``gains`` (Eq. 3): its gain, travel time, length and the largest
    slot it reaches (a slot beyond the table gains nothing)."""
    g, t, length, ms = _evaluate(
        graph.edges, gains, route_scratch(thread_scratch, gains), counted, taxi, edges, float(depart_s)
    )
    return float(g), float(t), float(length), int(ms)


@compiled
def _plan_one(
    net: KappaGraph,
    scratch: RouteScratch,
    gains: Gains,
    counted: Counted,
    kappas: NDArray[np.float64],
    drive: Drive,
    fastest: NDArray[np.int64],
    depart_s: float,
) -> tuple[int, NDArray[np.int64], float, float, float, int]:
    """``plan_one`` in one compiled call: (kappa index (-1: unreachable), edges, gain, time, length, largest
    slot) of the best route."""
    scratch = scratch
    mark(scratch.zmask, counted, drive.i, True)
    umax = _umax_scan(net, gains, scratch.zmask)
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
            costs, lazy = _own_metric(net, scratch, gains, ki, kappa, umax)
            edges = _guided_path(net, scratch.forward, costs, lazy, drive, net.floor_lm)
            if scratch.forward.info[1] == -1:
                best_k = -1
                break
        else:
            continue
        g, t, length, ms = _eval_stamped(net.ed, gains, scratch, edges, depart_s)
        phi = g / t if t > 0 else 0.0
        if phi > best_phi:
            best_phi = phi
            best_k = ki
            best_edges = edges
            best_g = g
            best_t = t
            best_l = length
            best_ms = ms
    mark(scratch.zmask, counted, drive.i, False)
    return best_k, best_edges, best_g, best_t, best_l, best_ms


def plan_one(
    graph: RoadGraph,
    gains: Gains,
    counted: Counted,
    drive: Drive,
    fastest: NDArray[np.int64],
    kappas: Sequence[float],
    depart_s: float,
    thread_scratch: Scratch,
) -> Route:
    """Algorithm 1 from taxi ``drive.i`` to one target, its fastest path given (the kappa = 0 cost is the
    travel time whatever the gains, so the fastest path does not change when the gains do)."""
    kap = np.asarray(kappas, dtype=np.float64)
    kt = kappa_graph(graph, tuple(kap.tolist()))
    ki, edges, g, t, length, ms = _plan_one(
        kt,
        route_scratch(thread_scratch, gains),
        gains,
        counted,
        kap,
        drive,
        np.asarray(fastest, dtype=np.int64),
        float(depart_s),
    )
    if ki < 0:
        raise ValueError(f"node {drive.target} cannot be reached from node {drive.source}")
    return Route(
        drive.source, drive.target, float(kap[ki]), edges, float(g), float(t), float(length), int(ms)
    )
