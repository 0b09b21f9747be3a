"""Paths on the network and the enhanced A* drive-by sensing routes (Algorithm 1 and 2; METHOD section 5).

Algorithm 1 for one taxi is a best-first search on the utility-discounted cost
``c_e = t_e (1 - kappa u_e)``; with ``u_e`` fixed for the epoch this is a static non-negative weight, so one
one-to-many Dijkstra tree per (taxi, kappa) serves every POI at once (the straight-line A* heuristic would
only prune the search; the tree it settles is the same). Each candidate route is then evaluated exactly
(first visit per cell and interval) and the kappa with the largest phi = gain / time is kept; kappa = 0 is
the plain fastest path, so the result is never worse than the fastest path.
"""

from __future__ import annotations

import functools
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from services import contraction, kernels
from services.city import City
from services.model import CountsView, IntervalKey, TaxiId
from services.sensing import theta_gain, timed_cells

__all__ = [
    "GraphArrays",
    "graph_arrays",
    "GainTable",
    "gain_table",
    "Route",
    "RouteSet",
    "plan_routes",
    "joint_utility",
    "improve_routes",
    "path_nodes",
]


@dataclass(frozen=True, slots=True, eq=False)
class GraphArrays:
    """Flat arrays of a city's network in the forms the kernels want (forward and reverse CSR)."""

    indptr: NDArray[np.int64]
    head: NDArray[np.int32]
    tail: NDArray[np.int32]
    time_s: NDArray[np.float64]
    length_m: NDArray[np.float64]
    rev_indptr: NDArray[np.int64]
    rev_head: NDArray[np.int32]  # reverse edge j goes head_j <- ... i.e. to the original tail
    rev_edge: NDArray[np.int64]  # original edge id of reverse edge j
    rev_time_s: NDArray[np.float64]
    rev_length_m: NDArray[np.float64]
    ec_ptr: NDArray[np.int64]
    ec_cell: NDArray[np.int32]
    ec_frac: NDArray[np.float64]
    min_speed_mps: float

    @property
    def cells(self) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.float64]]:
        """``(ec_ptr, ec_cell, ec_frac)``: the cells each edge crosses, as the kernels take them."""
        return self.ec_ptr, self.ec_cell, self.ec_frac


@functools.lru_cache(maxsize=16)
def graph_arrays(city: City) -> GraphArrays:
    """Build (once per city) the forward and reverse CSR arrays."""
    net = city.network
    order = np.lexsort((net.edge_u, net.edge_v))
    rev_indptr = np.zeros(net.n_nodes + 1, dtype=np.int64)
    np.add.at(rev_indptr, net.edge_v.astype(np.int64) + 1, 1)
    rev_indptr = np.cumsum(rev_indptr)
    speed = net.edge_length_m / np.maximum(net.edge_time_s, 1e-12)
    return GraphArrays(
        indptr=net.indptr.astype(np.int64),
        head=net.edge_v.astype(np.int32),
        tail=net.edge_u.astype(np.int32),
        time_s=net.edge_time_s.astype(np.float64),
        length_m=net.edge_length_m.astype(np.float64),
        rev_indptr=rev_indptr,
        rev_head=net.edge_u[order].astype(np.int32),
        rev_edge=order.astype(np.int64),
        rev_time_s=net.edge_time_s[order].astype(np.float64),
        rev_length_m=net.edge_length_m[order].astype(np.float64),
        ec_ptr=city.edge_cells.ptr.astype(np.int64),
        ec_cell=city.edge_cells.cell.astype(np.int32),
        ec_frac=city.edge_cells.frac.astype(np.float64),
        min_speed_mps=float(speed[speed > 0].min()) if (speed > 0).any() else 1.0,
    )


def path_nodes(city: City, start: int, edges: NDArray[np.int64]) -> tuple[int, ...]:
    """Node sequence of a path given its start node and edges."""
    if len(edges) == 0:
        return (int(start),)
    return (int(city.network.edge_u[edges[0]]), *city.network.edge_v[edges].tolist())


@dataclass(slots=True)
class GainTable:
    """Marginal terms mu_t s_g ((L+1)^rho - L^rho) for intervals ``k0 .. k0+S-1`` (rows) and all cells.

    ``base`` ignores who is asking; ``for_taxi`` zeroes the pairs the taxi is already counted in. ``unit``
    is the quantum of the integer copy used for exact tie-breaking (``matching``).
    """

    city: City
    k0: int
    base: NDArray[np.float64]
    unit: float = 1.0
    _shift: float = 0.0
    _stamp: NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))
    _next_stamp: int = 1
    _positive: tuple[list[int], list[int]] | None = None  # (slot, cell) of the positive terms, when needed

    @property
    def shift_s(self) -> float:
        """``interval_shift_s`` for the kernels: slot = floor((t + shift) / interval) - k0."""
        return float(self._shift)

    @property
    def clock(self) -> tuple[float, float, int]:
        """``(interval_shift_s, interval_s, k0)``: how the kernels turn a time into a row of the table."""
        return float(self._shift), float(self.city.horizon.interval_s), self.k0

    def for_taxi(
        self, visited: frozenset[tuple[IntervalKey, int]] | None
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """The terms for one taxi (``base`` with the pairs it is counted in set to 0) and their integer copy.

        Only positive terms can change, so the work is the smaller of walking ``visited`` and looking up
        the positive terms in it (none at all outside the horizon, where every term is 0).
        """
        g = self.base
        if visited:
            if self._positive is None:
                ps, pc = np.nonzero(g > 0.0)
                self._positive = (ps.tolist(), pc.tolist())
            pos_s, pos_c = self._positive
            if pos_s:
                g = g.copy()
                if len(visited) <= len(pos_s):
                    for k, c in visited:
                        s = int(k) - self.k0
                        if 0 <= s < g.shape[0]:
                            g[s, c] = 0.0
                else:
                    k0 = self.k0
                    for s, c in zip(pos_s, pos_c, strict=True):
                        if (k0 + s, c) in visited:
                            g[s, c] = 0.0
        return g, np.rint(g / self.unit).astype(np.int64)

    def stamps(self, n: int) -> tuple[NDArray[np.int64], int]:
        """A scratch array for the kernels and the first of ``n`` fresh stamp ids."""
        if self._stamp.shape != self.base.shape:
            self._stamp = np.zeros(self.base.shape, dtype=np.int64)
            self._next_stamp = 1
        first = self._next_stamp
        self._next_stamp += n
        return self._stamp, first


def gain_table(
    city: City,
    counts: Mapping[IntervalKey, NDArray[np.int64]],
    k0: int,
    n_slots: int,
    depart_s: float,
    extra: Mapping[tuple[int, int], int] | None = None,
) -> GainTable:
    """Marginal terms for intervals ``k0..k0+n_slots-1`` given ``counts`` (+ ``extra`` planned visits)."""
    rho = city.params.rho
    n_cells = city.grid.n_cells
    base = np.zeros((n_slots, n_cells))
    for s in range(n_slots):
        k = IntervalKey(k0 + s)
        lam = counts.get(k)
        lam_f = np.zeros(n_cells) if lam is None else lam.astype(np.float64)
        if extra:
            lam_f = lam_f.copy()
            for (kk, c), n in extra.items():
                if kk == k:
                    lam_f[c] += n
        base[s] = city.mu(k) * city.cell_weight * theta_gain(lam_f, 1.0, rho)
    return GainTable(city=city, k0=k0, base=base, _shift=city.horizon.shift_s(depart_s))


@dataclass(frozen=True, slots=True)
class Route:
    """One monitoring route: taxi, target node, kappa used, edges and its exact evaluation."""

    taxi_id: TaxiId
    source: int
    target: int
    kappa: float
    edges: NDArray[np.int64]
    gain: float
    time_s: float
    length_m: float

    @property
    def efficiency(self) -> float:
        """phi = gain / travel time (Eq. 12); 0 for a zero-length route."""
        return self.gain / self.time_s if self.time_s > 0 else 0.0


def _kappa_costs(
    ga: GraphArrays, cell_value: NDArray[np.float64], kappas: Sequence[float]
) -> list[tuple[float, NDArray[np.float64]]]:
    """Edge costs t_e (1 - kappa u_e) for each kappa; kappas > 0 are dropped when u is all zero."""
    u = kernels.entered_utility(ga.ec_ptr, ga.ec_cell, cell_value)
    umax = float(u.max()) if len(u) else 0.0
    out: list[tuple[float, NDArray[np.float64]]] = []
    for kappa in kappas:
        if kappa == 0.0:
            out.append((0.0, ga.time_s))
        elif umax > 0.0:
            out.append((float(kappa), ga.time_s * (1.0 - kappa * (u / umax))))
    return out


@dataclass(frozen=True, slots=True, eq=False)
class RouteSet:
    """Algorithm 1 from one taxi to many targets: per target the best kappa's evaluation; the route's edges
    are read off that kappa's tree only when asked for (most candidate routes are never used)."""

    taxi_id: TaxiId
    source: int
    targets: NDArray[np.int64]
    kappa: NDArray[np.float64]
    gain: NDArray[np.float64]
    time_s: NDArray[np.float64]
    length_m: NDArray[np.float64]
    tree: NDArray[np.int64]  # index into ``preds`` of the best kappa, per target
    preds: tuple[NDArray[np.int64], ...]
    tail: NDArray[np.int32]

    @property
    def efficiency(self) -> NDArray[np.float64]:
        """phi per target (0 for a zero-length route)."""
        t = self.time_s
        return np.divide(self.gain, t, out=np.zeros_like(self.gain), where=t > 0)

    def route(self, i: int) -> Route:
        edges = kernels.walk_edges(self.preds[int(self.tree[i])], self.tail, int(self.targets[i]))
        return Route(
            self.taxi_id,
            self.source,
            int(self.targets[i]),
            float(self.kappa[i]),
            edges,
            float(self.gain[i]),
            float(self.time_s[i]),
            float(self.length_m[i]),
        )


def plan_routes(
    city: City,
    table: GainTable,
    taxi_id: TaxiId,
    source: int,
    visited: frozenset[tuple[IntervalKey, int]] | None,
    targets: NDArray[np.int64],
    depart_s: float,
) -> tuple[RouteSet, int]:
    """Algorithm 1 from one taxi to every target: the best-phi route over the kappa family.

    Returns the routes (one per target, same order) and the largest interval slot any route reached.
    Ties in phi keep the smaller kappa, so kappa = 0 (the fastest path) wins unless beaten.
    """
    ga = graph_arrays(city)
    gain, gain_q = table.for_taxi(visited)
    k = len(targets)
    if contraction.ENABLED:
        return _plan_routes_fused(city, ga, table, gain, gain_q, taxi_id, source, targets, depart_s)
    best_phi = np.full(k, -np.inf)
    out_g, out_t, out_l = np.zeros(k), np.full(k, np.nan), np.zeros(k)
    out_kappa, out_tree = np.zeros(k), np.zeros(k, dtype=np.int64)
    preds: list[NDArray[np.int64]] = []
    max_slot = 0
    for kappa, cost in _kappa_costs(ga, gain[0], city.params.kappas):
        _dist, pred, _ = contraction.dijkstra(ga, cost, source, np.inf, targets, ga.time_s)
        stamp, first = table.stamps(k)
        g, _gq, t, length, ms = kernels.eval_targets(
            pred,
            ga.tail,
            targets,
            depart_s,
            ga.time_s,
            ga.length_m,
            *ga.cells,
            *table.clock,
            gain,
            gain_q,
            stamp,
            first,
        )
        max_slot = max(max_slot, int(ms))
        reached = ~np.isnan(t) & ((pred[targets] >= 0) | (targets == source))
        phi = np.divide(g, t, out=np.zeros_like(g), where=reached & (t > 0))
        better = reached & (phi > best_phi)
        best_phi[better] = phi[better]
        out_g[better], out_t[better], out_l[better] = g[better], t[better], length[better]
        out_kappa[better] = kappa
        out_tree[better] = len(preds)
        preds.append(pred)
    missing = targets[np.isinf(best_phi)]
    if len(missing):
        raise ValueError(f"targets unreachable from node {source}: {missing[:5].tolist()}")
    rs = RouteSet(taxi_id, source, targets, out_kappa, out_g, out_t, out_l, out_tree, tuple(preds), ga.tail)
    return rs, max_slot


def _plan_routes_fused(
    city: City,
    ga: GraphArrays,
    table: GainTable,
    gain: NDArray[np.float64],
    gain_q: NDArray[np.int64],
    taxi_id: TaxiId,
    source: int,
    targets: NDArray[np.int64],
    depart_s: float,
) -> tuple[RouteSet, int]:
    """``plan_routes`` in one compiled call (``kernels.plan_kappas``) on the contracted graph."""
    c = contraction.forward(ga)
    kappas = np.asarray(city.params.kappas, dtype=np.float64)
    idx, g, t, length, preds, max_slot = kernels.plan_kappas(
        *c.arrays,
        ga.tail,
        ga.time_s,
        ga.length_m,
        *ga.cells,
        kappas,
        int(source),
        targets,
        float(depart_s),
        *table.clock,
        gain,
        gain_q,
    )
    missing = targets[idx < 0]
    if len(missing):
        raise ValueError(f"targets unreachable from node {source}: {missing[:5].tolist()}")
    rs = RouteSet(taxi_id, source, targets, kappas[idx], g, t, length, idx, tuple(preds), ga.tail)
    return rs, int(max_slot)


def route_pairs(
    city: City, route: Route, visited: frozenset[tuple[IntervalKey, int]] | None, depart_s: float
) -> set[tuple[int, int]]:
    """The (interval, cell) pairs a route would add to Lambda (first visits not already counted)."""
    tc = timed_cells(city, route.edges, depart_s)
    seen = visited or frozenset()
    return {p for p in tc.pairs() if p not in seen}


def joint_utility(
    city: City, counts: Mapping[IntervalKey, NDArray[np.int64]], pair_sets: Sequence[set[tuple[int, int]]]
) -> float:
    """Marginal Gamma of several routes together: sum mu s ((L + n)^rho - L^rho), n = taxis per pair."""
    n: Counter[tuple[int, int]] = Counter()
    for ps in pair_sets:
        n.update(ps)
    return _joint_from_counts(city, counts, n)


def _joint_from_counts(
    city: City, counts: Mapping[IntervalKey, NDArray[np.int64]], n: Mapping[tuple[int, int], int]
) -> float:
    rho = city.params.rho
    total = 0.0
    for (k, c), cnt in n.items():
        if cnt <= 0:
            continue
        lam_arr = counts.get(IntervalKey(k))
        lam = float(lam_arr[c]) if lam_arr is not None else 0.0
        total += city.mu(k) * float(city.cell_weight[c]) * float(theta_gain(lam, cnt, rho))
    return total


def improve_routes(
    city: City,
    counts: CountsView,
    routes: list[Route],
    depart_s: float,
    n_slots: int,
) -> tuple[list[Route], list[float], int]:
    """Algorithm 2: re-plan each taxi's route against the others' planned visits; keep improvements.

    Each taxi keeps its POI. A re-planned route replaces the current one only if the joint utility of all
    routes rises. Stops after a pass without change or ``max_iter`` passes. Returns the routes, the joint
    utility after the initial matching and after every pass (non-decreasing), and the number of passes.
    """
    k0 = int(city.horizon.intervals_of(np.array([depart_s]))[0])
    visited = [counts.visited.get(r.taxi_id, frozenset()) for r in routes]
    pairs = [route_pairs(city, r, v, depart_s) for r, v in zip(routes, visited, strict=True)]
    total: Counter[tuple[int, int]] = Counter()
    for ps in pairs:
        total.update(ps)
    history = [_joint_from_counts(city, counts.counts, total)]
    passes = 0
    accepted = 0  # routes replaced so far; a taxi re-planned since the last replacement would repeat itself
    planned_at = [-1] * len(routes)
    for _ in range(city.params.max_iter):
        passes += 1
        changed = False
        for i, r in enumerate(routes):
            if planned_at[i] == accepted:
                continue
            planned_at[i] = accepted
            others = total.copy()
            others.subtract(pairs[i])
            table = gain_table(city, counts.counts, k0, n_slots, depart_s, extra=+others)
            rs, _ = plan_routes(
                city, table, r.taxi_id, r.source, visited[i], np.array([r.target], dtype=np.int64), depart_s
            )
            cand = rs.route(0)
            if np.array_equal(cand.edges, r.edges):
                continue
            cand_pairs = route_pairs(city, cand, visited[i], depart_s)
            trial = others.copy()
            trial.update(cand_pairs)
            u_new = _joint_from_counts(city, counts.counts, trial)
            if u_new > history[-1] * (1 + 1e-12) + 1e-300:
                routes[i] = cand
                pairs[i] = cand_pairs
                total = trial
                history.append(u_new)
                accepted += 1
                planned_at[i] = accepted
                changed = True
        if not changed:
            break
    return routes, history, passes
