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
import os
import threading
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from services import contraction, kernels
from services.city import City
from services.model import CountsView, IntervalKey, TaxiId
from services.sensing import theta_gain

__all__ = [
    "GraphArrays",
    "graph_arrays",
    "GainTable",
    "gain_table",
    "Route",
    "RouteSet",
    "CountedIn",
    "counted_in",
    "plan_routes",
    "joint_utility",
    "improve_routes",
    "path_nodes",
    "timed_pairs",
    "WORKERS",
    "parallel_map",
]

_T = TypeVar("_T")
_R = TypeVar("_R")


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


WORKERS = min(4, _cpus())
"""Threads that share independent searches (Step 3's taxis, the riders' pickup and service searches,
Algorithm 2's re-plans). The compiled kernels release the GIL, so on a machine with a free core they run side
by side; results are collected in order, so decisions do not depend on it. 1 runs everything on the
calling thread."""

_pool: tuple[ThreadPoolExecutor, int, int] | None = None  # (pool, its workers, the process it was made in)
_pool_lock = threading.Lock()


def parallel_map(fn: Callable[[_T], _R], items: Sequence[_T]) -> list[_R]:
    """``[fn(x) for x in items]``, the items split into contiguous chunks run on ``WORKERS`` threads when
    there are enough of them. ``fn`` must not itself call ``parallel_map``. The first exception (in item
    order) is raised, as the serial loop would."""
    global _pool
    workers = WORKERS
    if workers <= 1 or len(items) < 2 * workers:
        return [fn(x) for x in items]
    with _pool_lock:
        if _pool is None or _pool[1:] != (workers, os.getpid()):  # a forked child has none of the threads
            _pool = (
                ThreadPoolExecutor(max_workers=workers, thread_name_prefix="sd-search"),
                workers,
                os.getpid(),
            )
        pool = _pool[0]
    n_chunks = min(len(items), 4 * workers)
    bounds = np.linspace(0, len(items), n_chunks + 1).astype(int).tolist()
    futures = [
        pool.submit(lambda a, b: [fn(x) for x in items[a:b]], a, b)
        for a, b in zip(bounds[:-1], bounds[1:], strict=True)
    ]
    out: list[_R] = []
    for f in futures:
        out.extend(f.result())
    return out


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
        """The terms for one taxi (``base`` with the pairs it is counted in set to 0), and their integers."""
        return self.zeroed(counted_in(visited, self.k0))

    def zeroed(
        self, counted: tuple[NDArray[np.int64], NDArray[np.int64]]
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """``for_taxi`` given the taxi's pairs as arrays of intervals and cells (``counted_in``)."""
        g = self.base
        rows = counted[0] - self.k0
        keep = (rows >= 0) & (rows < g.shape[0])
        if keep.any():
            g = g.copy()
            g[rows[keep], counted[1][keep]] = 0.0
        return g, np.rint(g / self.unit).astype(np.int64)

    def stamps(self, n: int) -> tuple[NDArray[np.int64], int]:
        """A scratch array for the kernels and the first of ``n`` fresh stamp ids."""
        if self._stamp.shape != self.base.shape:
            self._stamp = np.zeros(self.base.shape, dtype=np.int64)
            self._next_stamp = 1
        first = self._next_stamp
        self._next_stamp += n
        return self._stamp, first


_NO_PAIRS = np.zeros(0, dtype=np.int64)


def counted_in(
    visited: frozenset[tuple[IntervalKey, int]] | None, k_min: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The (interval, cell) pairs of ``visited`` from interval ``k_min`` on, as two arrays."""
    if not visited:
        return _NO_PAIRS, _NO_PAIRS
    ks: list[int] = []
    cs: list[int] = []
    for k, c in visited:
        if k >= k_min:
            ks.append(int(k))
            cs.append(int(c))
    return np.array(ks, dtype=np.int64), np.array(cs, dtype=np.int64)


class CountedIn:
    """Per epoch: each taxi's ``counted_in`` pairs from interval ``k0`` on, built once per taxi (the gain
    tables of Steps 1 and 3 and of every Algorithm 2 re-plan zero the same pairs)."""

    def __init__(self, visited: Mapping[TaxiId, frozenset[tuple[IntervalKey, int]]], k0: int) -> None:
        self._visited = visited
        self._k0 = k0
        self._memo: dict[TaxiId, tuple[NDArray[np.int64], NDArray[np.int64]]] = {}

    def __call__(self, taxi_id: TaxiId) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        got = self._memo.get(taxi_id)
        if got is None:
            got = self._memo[taxi_id] = counted_in(self._visited.get(taxi_id), self._k0)
        return got


def gain_table(
    city: City,
    counts: Mapping[IntervalKey, NDArray[np.int64]],
    k0: int,
    n_slots: int,
    depart_s: float,
    extra: Mapping[tuple[int, int], int] | None = None,
    extra_counts: NDArray[np.int64] | None = None,
) -> GainTable:
    """Marginal terms for intervals ``k0..k0+n_slots-1`` given ``counts`` (+ ``extra`` planned visits per
    (interval, cell), or the same as a dense ``extra_counts[slot, cell]``; counts are whole numbers, so
    either way Lambda + n is exact)."""
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
        if extra_counts is not None:
            lam_f = lam_f + extra_counts[s]
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
    kappas: tuple[float, ...]  # the kappa of each tree in ``preds``
    tail: NDArray[np.int32]

    @property
    def efficiency(self) -> NDArray[np.float64]:
        """phi per target (0 for a zero-length route)."""
        t = self.time_s
        return np.divide(self.gain, t, out=np.zeros_like(self.gain), where=t > 0)

    def path(self, i: int, kappa: float) -> NDArray[np.int64] | None:
        """Edges of the route to target ``i`` on the tree of ``kappa`` (None if that tree was not grown)."""
        for ki, (k, pred) in enumerate(zip(self.kappas, self.preds, strict=True)):
            if k == kappa and (pred[int(self.targets[i])] >= 0 or int(self.targets[i]) == self.source):
                edges: NDArray[np.int64] = kernels.walk_edges(self.preds[ki], self.tail, int(self.targets[i]))
                return edges
        return None

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
    *,
    counted: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
    fastest: NDArray[np.int64] | None = None,
) -> tuple[RouteSet, int]:
    """Algorithm 1 from one taxi to every target: the best-phi route over the kappa family.

    Returns the routes (one per target, same order) and the largest interval slot any route reached.
    Ties in phi keep the smaller kappa, so kappa = 0 (the fastest path) wins unless beaten.

    ``counted`` is ``visited`` as ``counted_in`` arrays, when the caller has them. ``fastest``, for a single
    target, is the kappa = 0 tree path to it when already known: the kappa = 0 cost is the travel time
    whatever the gains, and a search's tree path to a node it settles does not depend on the other targets
    (the search is the same up to the moment the node is settled), so that path is taken instead of
    searching again.
    """
    ga = graph_arrays(city)
    gain, gain_q = table.for_taxi(visited) if counted is None else table.zeroed(counted)
    k = len(targets)
    if fastest is not None and k != 1:
        raise ValueError("fastest: one target only")
    if contraction.ENABLED:
        return _plan_routes_fused(city, ga, table, gain, gain_q, taxi_id, source, targets, depart_s, fastest)
    best_phi = np.full(k, -np.inf)
    out_g, out_t, out_l = np.zeros(k), np.full(k, np.nan), np.zeros(k)
    out_kappa, out_tree = np.zeros(k), np.zeros(k, dtype=np.int64)
    preds: list[NDArray[np.int64]] = []
    grown: list[float] = []
    stamps = np.zeros(gain.shape, dtype=np.int64)
    max_slot = 0
    for kappa, cost in _kappa_costs(ga, gain[0], city.params.kappas):
        if kappa == 0.0 and fastest is not None:
            pred = np.full(city.network.n_nodes, -1, dtype=np.int64)
            pred[ga.head[fastest]] = fastest
        else:
            _dist, pred, _ = contraction.dijkstra(ga, cost, source, np.inf, targets, ga.time_s)
        stamp, first = (
            stamps,
            1 + len(preds) * k,
        )  # a scratch array of this call's own: threads may share the table
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
        grown.append(kappa)
    missing = targets[np.isinf(best_phi)]
    if len(missing):
        raise ValueError(f"targets unreachable from node {source}: {missing[:5].tolist()}")
    rs = RouteSet(
        taxi_id,
        source,
        targets,
        out_kappa,
        out_g,
        out_t,
        out_l,
        out_tree,
        tuple(preds),
        tuple(grown),
        ga.tail,
    )
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
    fastest: NDArray[np.int64] | None,
) -> tuple[RouteSet, int]:
    """``plan_routes`` in one compiled call (``kernels.plan_kappas``) on the contracted graph."""
    c = contraction.forward(ga)
    kappas = np.asarray(city.params.kappas, dtype=np.float64)
    fixed = _NO_PAIRS if fastest is None else fastest
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
        fastest is not None,
        fixed,
        ga.head[fixed].astype(np.int64),
    )
    missing = targets[idx < 0]
    if len(missing):
        raise ValueError(f"targets unreachable from node {source}: {missing[:5].tolist()}")
    rs = RouteSet(
        taxi_id,
        source,
        targets,
        kappas[idx],
        g,
        t,
        length,
        idx,
        tuple(preds),
        tuple(kappas.tolist()),
        ga.tail,
    )
    return rs, int(max_slot)


def timed_pairs(city: City, edges: NDArray[np.int64], depart_s: float) -> list[tuple[IntervalKey, int]]:
    """``sensing.timed_cells(city, edges, depart_s).pairs()`` computed by the compiled kernels: the same
    crossing times (same operations in the same order), intervals and first-entry order."""
    ga = graph_arrays(city)
    cells, entry = kernels.crossings(np.asarray(edges, dtype=np.int64), float(depart_s), ga.time_s, *ga.cells)
    if len(cells) == 0:
        return []
    shift = city.horizon.shift_s(float(entry[0]))
    ks, cs = kernels.first_pairs(cells, entry, shift, float(city.horizon.interval_s), city.grid.n_cells)
    return list(zip(ks.tolist(), cs.tolist(), strict=True))


def route_pairs(
    city: City, route: Route, visited: frozenset[tuple[IntervalKey, int]] | None, depart_s: float
) -> set[tuple[int, int]]:
    """The (interval, cell) pairs a route would add to Lambda (first visits not already counted)."""
    seen = visited or frozenset()
    return {p for p in timed_pairs(city, route.edges, depart_s) if p not in seen}


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
    *,
    fastest: Sequence[NDArray[np.int64] | None] | None = None,
    counted: CountedIn | None = None,
) -> tuple[list[Route], list[float], int]:
    """Algorithm 2: re-plan each taxi's route against the others' planned visits; keep improvements.

    Each taxi keeps its POI. A re-planned route replaces the current one only if the joint utility of all
    routes rises. Stops after a pass without change or ``max_iter`` passes. Returns the routes, the joint
    utility after the initial matching and after every pass (non-decreasing), and the number of passes.

    ``fastest[i]``, when given, is the kappa = 0 path of route ``i``'s taxi to its POI (from Step 3): the
    re-plans take it instead of searching for it again (``plan_routes``). ``counted`` caches the taxis'
    counted pairs for the epoch. The others' planned visits enter the gain table as a dense count per
    (slot, cell), kept up to date as routes are replaced.
    """
    k0 = int(city.horizon.intervals_of(np.array([depart_s]))[0])
    visited = [counts.visited.get(r.taxi_id, frozenset()) for r in routes]
    counted = counted or CountedIn(counts.visited, k0)
    pairs = [route_pairs(city, r, v, depart_s) for r, v in zip(routes, visited, strict=True)]
    total: Counter[tuple[int, int]] = Counter()
    for ps in pairs:
        total.update(ps)
    n_cells = city.grid.n_cells

    def slots_cells(ps: set[tuple[int, int]]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        rows = np.array([k - k0 for k, _ in ps], dtype=np.int64)
        cells = np.array([c for _, c in ps], dtype=np.int64)
        keep = (rows >= 0) & (rows < n_slots)
        return rows[keep], cells[keep]

    dense = [slots_cells(ps) for ps in pairs]
    total_n = np.zeros((n_slots, n_cells), dtype=np.int64)
    for rows, cells in dense:
        total_n[rows, cells] += 1  # a route's pairs are distinct
    history = [_joint_from_counts(city, counts.counts, total)]
    zeros = [counted(r.taxi_id) for r in routes]
    targets = [np.array([r.target], dtype=np.int64) for r in routes]

    def replan(total_n: NDArray[np.int64], i: int) -> tuple[Route, NDArray[np.int64]]:
        """Route ``i`` re-planned against the counts plus the others' visits (``total_n`` less its own)."""
        r = routes[i]
        others_n = total_n.copy()
        others_n[dense[i]] -= 1
        table = gain_table(city, counts.counts, k0, n_slots, depart_s, extra_counts=others_n)
        rs, _ = plan_routes(
            city,
            table,
            r.taxi_id,
            r.source,
            visited[i],
            targets[i],
            depart_s,
            counted=zeros[i],
            fastest=fastest[i] if fastest is not None else None,
        )
        return rs.route(0), others_n

    # Re-plans are independent until one is accepted: a batch of the next ones is planned at once (on
    # WORKERS threads) and taken in order; after an acceptance the rest of the batch is planned again
    # against the new counts, so the outcome is that of one re-plan after the other.
    batch = 1 if WORKERS <= 1 else 4 * WORKERS
    passes = 0
    accepted = 0  # routes replaced so far; a taxi re-planned since the last replacement would repeat itself
    planned_at = [-1] * len(routes)
    for _ in range(city.params.max_iter):
        passes += 1
        changed = False
        i = 0
        while i < len(routes):
            todo: list[int] = []
            j = i
            while j < len(routes) and len(todo) < batch:
                if planned_at[j] != accepted:
                    todo.append(j)
                j += 1
            i = j
            for a, (cand, others_n) in zip(
                todo, parallel_map(functools.partial(replan, total_n), todo), strict=True
            ):
                planned_at[a] = accepted
                if np.array_equal(cand.edges, routes[a].edges):
                    continue
                cand_pairs = route_pairs(city, cand, visited[a], depart_s)
                others = total.copy()
                others.subtract(pairs[a])
                trial = others.copy()
                trial.update(cand_pairs)
                u_new = _joint_from_counts(city, counts.counts, trial)
                if u_new > history[-1] * (1 + 1e-12) + 1e-300:
                    routes[a] = cand
                    pairs[a] = cand_pairs
                    total = trial
                    dense[a] = slots_cells(cand_pairs)
                    total_n = others_n
                    total_n[dense[a]] += 1
                    history.append(u_new)
                    accepted += 1
                    planned_at[a] = accepted
                    changed = True
                    i = a + 1  # the rest of the batch saw the old counts
                    break
        if not changed:
            break
    return routes, history, passes
