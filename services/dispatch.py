"""One decision epoch: the three-step priority matching and Algorithm 2 (METHOD sections 4-6).

``decide`` is the single pure entry point: (city, counts, snapshot, tasks) -> Decision.

1. Step 1 (Eq. 4-7): vacant instrumented taxis x waiting riders within the pickup radius; weight = the
   marginal sensing gain of the service leg (pickup -> dropoff) for that taxi, departing when it reaches the
   rider; maximize total gain, then minimize total wait.
2. Step 2 (Eq. 8-11): vacant ordinary taxis x the remaining riders; maximize matches, then minimize wait.
3. Step 3 (Eq. 13-16): vacant instrumented taxis still free x open POIs (grouped by node); maximize
   matches, then total phi of the enhanced A* routes; then Algorithm 2 improves the routes.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services import contraction, kernels
from services.city import City
from services.matching import EXACT_LIMIT, lexicographic_weights, max_weight_matching, quantize
from services.model import (
    CountsView,
    Decision,
    IntervalKey,
    Rider,
    RiderId,
    RiderMatch,
    Snapshot,
    Task,
    TaskAssignment,
    TaskId,
    Taxi,
    Visit,
)
from services.routing import (
    CountedIn,
    GainTable,
    Route,
    RouteSet,
    gain_table,
    graph_arrays,
    improve_routes,
    parallel_map,
    path_nodes,
    plan_routes,
    timed_pairs,
)
from services.tasks import PlannedPath, apply_reaches, due_completions, reaches

__all__ = ["decide", "warm_up", "INITIAL_SLOTS"]

INITIAL_SLOTS = 3
"""Intervals (from the epoch's own) whose gains are tabulated first; more are added if a path needs them."""

_WAIT_UNIT_S = 1e-3  # waits are compared to the millisecond


@dataclass(frozen=True, slots=True)
class _Leg:
    edges: NDArray[np.int64]
    length_m: float
    time_s: float


def _g_route(city: City, edges: NDArray[np.int64]) -> tuple[tuple[int, int], ...]:
    """Ordered distinct cells crossed by the edges (first-entry order)."""
    if len(edges) == 0:
        return ()
    ga = graph_arrays(city)
    cells = kernels.distinct_cells(edges, ga.ec_ptr, ga.ec_cell, city.grid.n_cells)
    return tuple(city.grid.col_row(c) for c in cells.tolist())


@dataclass(frozen=True, slots=True)
class _Pickups:
    """Candidate pairs within the radius, as parallel arrays ordered by (rider, taxi): taxi index, rider
    index, pickup length and wait; and per rider the in-tree toward its origin (reverse-graph predecessor
    edges) from which a pickup leg is read off when the pair is matched."""

    taxi: NDArray[np.int64]
    rider: NDArray[np.int64]
    length_m: NDArray[np.float64]
    wait_s: NDArray[np.float64]
    pred_rev: list[NDArray[np.int64]]
    taxi_nodes: NDArray[np.int64]
    keys: NDArray[np.int64]  # rider * number of taxis + taxi: ascending

    def find(self, i: int, j: int) -> int:
        """Position of the pair (taxi ``i``, rider ``j``) in the arrays."""
        key = j * len(self.taxi_nodes) + i
        k = int(np.searchsorted(self.keys, key))
        if k >= len(self.keys) or self.keys[k] != key:
            raise KeyError((i, j))
        return k

    def leg(self, city: City, i: int, j: int) -> _Leg:
        ga = graph_arrays(city)
        pred = self.pred_rev[j]
        succ = np.where(pred >= 0, ga.rev_edge[np.maximum(pred, 0)], -1)
        edges = kernels.walk_succ(succ, ga.head, int(self.taxi_nodes[i]))
        k = self.find(i, j)
        return _Leg(edges, float(self.length_m[k]), float(self.wait_s[k]))


def _pickup_legs(city: City, riders: Sequence[Rider], taxis: Sequence[Taxi]) -> _Pickups:
    """Fastest pickup paths of every taxi within the matching radius of every rider (one in-tree each)."""
    ga = graph_arrays(city)
    radius = city.params.radius_m
    limit_s = radius / ga.min_speed_mps * (1 + 1e-9)
    taxi_nodes = np.array([t.node for t in taxis], dtype=np.int64)
    none = np.zeros(0, dtype=np.int64)

    def search(
        rider: Rider,
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        dist, pred_rev, length = contraction.dijkstra(
            ga,
            ga.rev_time_s,
            rider.origin,
            limit_s,
            none,
            ga.rev_length_m,
            reverse_graph=True,
            queries=taxi_nodes,
        )
        lt = length[taxi_nodes]
        wt = dist[taxi_nodes]
        ok = np.flatnonzero(np.isfinite(wt) & (lt <= radius + 1e-6))
        return pred_rev, ok, lt[ok], wt[ok]

    searched = parallel_map(search, riders)
    preds = [x[0] for x in searched]
    found = [x[1:] for x in searched] if len(taxi_nodes) else []
    counts = [len(ok) for ok, _, _ in found]
    if sum(counts):
        taxi = np.concatenate([ok for ok, _, _ in found]).astype(np.int64)
        rider_idx = np.repeat(np.arange(len(found), dtype=np.int64), counts)
        lengths = np.concatenate([x for _, x, _ in found])
        waits = np.concatenate([x for _, _, x in found])
    else:
        taxi = rider_idx = np.zeros(0, dtype=np.int64)
        lengths = waits = np.zeros(0)
    return _Pickups(taxi, rider_idx, lengths, waits, preds, taxi_nodes, rider_idx * len(taxi_nodes) + taxi)


def _service_leg(city: City, rider: Rider) -> _Leg:
    ga = graph_arrays(city)
    _dist, pred, _ = contraction.dijkstra(
        ga, ga.time_s, rider.origin, np.inf, np.array([rider.destination], dtype=np.int64), ga.length_m
    )
    if rider.destination != rider.origin and pred[rider.destination] < 0:
        raise ValueError(f"rider {rider.id}: destination unreachable from origin")
    edges = kernels.walk_edges(pred, ga.tail, rider.destination)
    return _Leg(edges, float(ga.length_m[edges].sum()), float(ga.time_s[edges].sum()))


def _eval_leg(
    city: City,
    table: GainTable,
    gain: NDArray[np.float64],
    gain_q: NDArray[np.int64],
    leg: _Leg,
    depart_s: float,
) -> tuple[float, int, int]:
    ga = graph_arrays(city)
    stamp, sid = table.stamps(1)
    g, gq, _t, _terms, ms = kernels.eval_path(
        leg.edges,
        depart_s,
        ga.time_s,
        *ga.cells,
        *table.clock,
        gain,
        gain_q,
        stamp,
        sid,
    )
    return float(g), int(gq), int(ms)


def _step1(
    city: City,
    counts: CountsView,
    now: float,
    k0: int,
    riders: Sequence[Rider],
    taxis: Sequence[Taxi],
    pickups: _Pickups,
    service: Sequence[_Leg],
    n_slots: int,
    counted: CountedIn,
) -> tuple[list[tuple[int, int, float]], int, dict[str, float | int]]:
    """Matched (taxi index, rider index, gain) of Step 1 and the slots needed."""
    instr = pickups.taxi < len(taxis)
    if not instr.any():
        return [], n_slots, {"step1_candidates": 0}
    ga = graph_arrays(city)
    pair_taxi = pickups.taxi[instr]
    pair_leg = pickups.rider[instr]
    wait = pickups.wait_s[instr]
    wait_q = quantize(wait, _WAIT_UNIT_S)
    leg_ptr = np.zeros(len(service) + 1, dtype=np.int64)
    leg_ptr[1:] = np.cumsum([len(leg.edges) for leg in service])
    leg_edges = (
        np.concatenate([leg.edges for leg in service]).astype(np.int64) if service else np.zeros(0, np.int64)
    )
    crossings = max(int((ga.ec_ptr[leg.edges + 1] - ga.ec_ptr[leg.edges]).sum()) for leg in service)
    n_match = min(len(taxis), len(riders))
    k_sec = int(wait_q.max()) * n_match + 1
    cap = EXACT_LIMIT // (4 * n_match * k_sec)
    used = np.unique(pair_taxi)
    taxis_used = used.tolist()
    pair_table = np.searchsorted(used, pair_taxi).astype(np.int64)
    while True:
        table = gain_table(city, counts.counts, k0, n_slots, now)
        term_max = float(table.base.max(initial=0.0))
        table.unit = max(term_max * max(crossings, 1) / max(cap, 1), 1e-300)
        per_taxi = [table.zeroed(counted(taxis[i].id)) for i in taxis_used]
        gains = np.stack([g for g, _ in per_taxi])
        gains_q = np.stack([q for _, q in per_taxi])
        stamp, first = table.stamps(len(pair_taxi))
        g, gq, max_slot = kernels.eval_pairs(
            pair_table,
            pair_leg,
            now + wait,
            leg_ptr,
            leg_edges,
            ga.time_s,
            *ga.cells,
            *table.clock,
            gains,
            gains_q,
            stamp,
            first,
        )
        if max_slot < n_slots:
            break
        n_slots = int(max_slot) + 1
    feasible = np.zeros((len(taxis), len(riders)), dtype=bool)
    prim = np.zeros(feasible.shape, dtype=np.int64)
    sec = np.zeros(feasible.shape, dtype=np.int64)
    feasible[pair_taxi, pair_leg] = True
    prim[pair_taxi, pair_leg] = gq
    sec[pair_taxi, pair_leg] = wait_q
    sol = max_weight_matching(lexicographic_weights(feasible, prim, sec, secondary_sense="min"))
    n = len(pickups.taxi_nodes)
    at = np.searchsorted(
        pair_leg * n + pair_taxi, sol.cols * n + sol.rows
    )  # pairs are ordered by (rider, taxi)
    out = [(int(i), int(j), float(g[k])) for i, j, k in zip(sol.rows, sol.cols, at, strict=True)]
    return out, n_slots, {"step1_candidates": len(pair_taxi), "step1_gain_unit": table.unit}


def _step2(riders_left: Sequence[int], taxis: Sequence[int], pickups: _Pickups) -> list[tuple[int, int]]:
    """Step 2 over global taxi/rider indices: maximize matches, then minimize total wait."""
    feasible = np.zeros((len(taxis), len(riders_left)), dtype=bool)
    sec = np.zeros(feasible.shape, dtype=np.int64)
    row = np.full(len(pickups.taxi_nodes), -1, dtype=np.int64)
    row[np.asarray(taxis, dtype=np.int64)] = np.arange(len(taxis))
    col = np.full(len(pickups.pred_rev), -1, dtype=np.int64)
    col[np.asarray(riders_left, dtype=np.int64)] = np.arange(len(riders_left))
    r, c = row[pickups.taxi], col[pickups.rider]
    ok = (r >= 0) & (c >= 0)
    feasible[r[ok], c[ok]] = True
    sec[r[ok], c[ok]] = quantize(pickups.wait_s[ok], _WAIT_UNIT_S)
    prim = feasible.astype(np.int64)
    sol = max_weight_matching(lexicographic_weights(feasible, prim, sec, secondary_sense="min"))
    return [(taxis[int(a)], riders_left[int(b)]) for a, b in zip(sol.rows, sol.cols, strict=True)]


def _step3(
    city: City,
    counts: CountsView,
    now: float,
    k0: int,
    taxis: Sequence[Taxi],
    targets: NDArray[np.int64],
    n_slots: int,
    counted: CountedIn,
) -> tuple[list[tuple[int, Route, NDArray[np.int64] | None]], int]:
    """Step 3: (taxi index, route, the kappa = 0 path to the same POI) for the matched taxi-POI pairs,
    before Algorithm 2."""
    if len(taxis) == 0 or len(targets) == 0:
        return [], n_slots
    pairs = [counted(taxi.id) for taxi in taxis]

    def plan(table: GainTable, a: int) -> tuple[RouteSet, int]:
        return plan_routes(city, table, taxis[a].id, taxis[a].node, None, targets, now, counted=pairs[a])

    while True:
        table = gain_table(city, counts.counts, k0, n_slots, now)
        planned = parallel_map(functools.partial(plan, table), range(len(taxis)))
        sets: list[RouteSet] = [rs for rs, _ in planned]
        max_slot = max(ms for _, ms in planned)
        if max_slot < n_slots:
            break
        n_slots = max_slot + 1
    phi = np.stack([rs.efficiency for rs in sets])
    phi_max = float(phi.max(initial=0.0))
    unit = phi_max / 2**24 if phi_max > 0 else 1.0
    feasible = np.ones(phi.shape, dtype=bool)
    sol = max_weight_matching(
        lexicographic_weights(feasible, feasible.astype(np.int64), quantize(phi, unit), secondary_sense="max")
    )
    return [
        (int(i), sets[int(i)].route(int(j)), sets[int(i)].path(int(j), 0.0))
        for i, j in zip(sol.rows, sol.cols, strict=True)
    ], n_slots


def _touching(city: City, paths: Sequence[PlannedPath], nodes: NDArray[np.bool_]) -> list[PlannedPath]:
    """The paths that pass through at least one of ``nodes`` (in order): the only ones ``tasks.reaches`` can
    find a pending task on, so it is given only these."""
    head = city.network.edge_v
    return [p for p in paths if nodes[p.start] or bool(nodes[head[p.edges]].any())]


def _visits(city: City, counts: CountsView, taxi: Taxi, edges: NDArray[np.int64], now: float) -> list[Visit]:
    seen = counts.visited.get(taxi.id, frozenset())
    return [Visit(taxi.id, k, c) for k, c in timed_pairs(city, edges, now) if (k, c) not in seen]


def decide(city: City, counts: CountsView, snapshot: Snapshot, tasks: Sequence[Task]) -> Decision:
    """Solve one epoch (METHOD sections 4-6). Pure: reads nothing but its arguments, changes nothing.

    Parameters
    ----------
    city : the served city (network, grid, weights, parameters).
    counts : Lambda per interval and the (interval, cell) pairs each taxi is already counted in, as of the
        start of the epoch.
    snapshot : waiting riders and taxi states, resolved to node indices.
    tasks : every monitoring task of the city (any status).

    Returns
    -------
    Decision with the rider matches of Steps 1-2, the monitoring routes of Step 3 (after Algorithm 2), the
    task updates, the visits to count on commit, and per-step diagnostics in ``stats``.
    """
    p = city.params
    now = snapshot.time_s
    k0 = int(city.horizon.interval_of(now))
    expired = tuple(r.id for r in snapshot.riders if now - r.requested_at_s > p.patience_s)
    expired_set = set(expired)
    riders = [r for r in snapshot.riders if r.id not in expired_set]
    vacant = [t for t in snapshot.taxis if t.vacant]
    instr = [t for t in vacant if t.instrumented]
    ordinary = [t for t in vacant if not t.instrumented]
    taxis = instr + ordinary  # instrumented first: indices < len(instr) are instrumented

    pickups = _pickup_legs(city, riders, taxis)
    service = parallel_map(functools.partial(_service_leg, city), riders)
    n_slots = INITIAL_SLOTS

    # Step 1
    counted = CountedIn(counts.visited, k0)
    s1, n_slots, s1_stats = _step1(city, counts, now, k0, riders, instr, pickups, service, n_slots, counted)
    matches: list[RiderMatch] = []
    planned: list[PlannedPath] = []
    visits: list[Visit] = []
    busy_taxis: set[int] = set()
    taken: set[int] = set()
    for i, j, gain in s1:
        leg, svc = pickups.leg(city, i, j), service[j]
        edges = np.concatenate((leg.edges, svc.edges)).astype(np.int64)
        taxi, rider = taxis[i], riders[j]
        matches.append(
            RiderMatch(
                1,
                taxi.id,
                rider.id,
                leg.length_m,
                leg.time_s,
                svc.length_m,
                svc.time_s,
                gain,
                path_nodes(city, taxi.node, edges),
                _g_route(city, edges),
            )
        )
        planned.append(PlannedPath(taxi.id, taxi.node, edges, now))
        visits.extend(_visits(city, counts, taxi, edges, now))
        busy_taxis.add(i)
        taken.add(j)

    # Step 2
    left = [j for j in range(len(riders)) if j not in taken]
    ord_idx = list(range(len(instr), len(taxis)))
    for i, j in _step2(left, ord_idx, pickups):
        leg, svc = pickups.leg(city, i, j), service[j]
        edges = np.concatenate((leg.edges, svc.edges)).astype(np.int64)
        matches.append(
            RiderMatch(
                2,
                taxis[i].id,
                riders[j].id,
                leg.length_m,
                leg.time_s,
                svc.length_m,
                svc.time_s,
                0.0,
                path_nodes(city, taxis[i].node, edges),
                _g_route(city, edges),
            )
        )
        taken.add(j)
    unmatched = tuple(riders[j].id for j in range(len(riders)) if j not in taken)

    # Step 3: open tasks not already reached by a Step 1 path, grouped by POI node
    task_nodes = np.zeros(city.network.n_nodes, dtype=bool)
    task_nodes[[t.node for t in tasks if t.status == "pending"]] = True
    passive1 = reaches(city, _touching(city, planned, task_nodes), tasks)
    open_tasks = sorted(
        (t for t in tasks if t.is_open(now) and t.id not in passive1), key=lambda t: (t.scheduled_at_s, t.id)
    )
    by_node: dict[int, TaskId] = {}
    for t in open_tasks:
        by_node.setdefault(t.node, t.id)
    targets = np.fromiter(by_node, dtype=np.int64, count=len(by_node))
    free = [t for i, t in enumerate(instr) if i not in busy_taxis]
    assignments: list[TaskAssignment] = []
    history: list[float] = []
    passes = 0
    if p.active_sensing and free and len(targets):
        s3, n_slots = _step3(city, counts, now, k0, free, targets, n_slots, counted)
        routes, history, passes = improve_routes(
            city, counts, [r for _, r, _ in s3], now, n_slots, fastest=[f for _, _, f in s3], counted=counted
        )
        base = gain_table(city, counts.counts, k0, n_slots, now)
        for (i, _, _), route in zip(s3, routes, strict=True):
            taxi = free[i]
            g, _gq, _ms = _eval_leg(
                city,
                base,
                *base.zeroed(counted(taxi.id)),
                _Leg(route.edges, route.length_m, route.time_s),
                now,
            )
            task_id = by_node[route.target]
            assignments.append(
                TaskAssignment(
                    taxi.id,
                    task_id,
                    path_nodes(city, taxi.node, route.edges),
                    _g_route(city, route.edges),
                    route.length_m,
                    route.time_s,
                    g,
                    g / route.time_s if route.time_s > 0 else 0.0,
                    p.unit_cost_cny_per_km * route.length_m / 1000.0,
                    route.kappa,
                )
            )
            planned.append(PlannedPath(taxi.id, taxi.node, route.edges, now, target_task=task_id))
            visits.extend(_visits(city, counts, taxi, route.edges, now))

    found = reaches(city, _touching(city, planned, task_nodes), tasks)
    updates = {t.id: t for t in due_completions(tasks, now)}
    updates.update({t.id: t for t in apply_reaches(tasks, found, now)})
    task_updates = tuple(updates.values())
    completed = tuple(t for t in task_updates if t.status == "completed")
    touched = sorted({IntervalKey(k0 + s) for s in range(n_slots)} | {v.interval for v in visits})
    stats: dict[str, float | int] = {
        "interval": k0,
        "riders": len(snapshot.riders),
        "riders_expired": len(expired),
        "vacant_instrumented": len(instr),
        "vacant_ordinary": len(ordinary),
        "step1_matches": len(s1),
        "step2_matches": len(matches) - len(s1),
        "step3_assignments": len(assignments),
        "step1_sensing_gain": float(sum(g for _, _, g in s1)),
        "total_wait_s": float(sum(m.wait_s for m in matches)),
        "open_tasks": len(open_tasks),
        "passive_reaches": sum(1 for r in found.values() if r.mode == "passive"),
        "alg2_passes": passes,
        "alg2_utility_initial": history[0] if history else 0.0,
        "alg2_utility_final": history[-1] if history else 0.0,
        "monitoring_cost_cny": float(sum(a.cost_cny for a in assignments)),
        **s1_stats,
    }
    return Decision(
        epoch_id=snapshot.epoch_id,
        time_s=now,
        rider_matches=tuple(matches),
        task_assignments=tuple(assignments),
        tasks_completed=completed,
        task_updates=task_updates,
        unmatched_rider_ids=unmatched,
        expired_rider_ids=tuple(RiderId(r) for r in expired),
        visits=tuple(dict.fromkeys(visits)),
        intervals_touched=tuple(touched),
        stats=stats,
    )


def warm_up(city: City) -> None:
    """Solve a tiny epoch on ``city`` so the compiled kernels are loaded before the first real request."""
    from services.model import TaskId, TaxiId

    n = city.network.n_nodes
    a, b = 0, n - 1
    t = 86400.0 * 20000 + 12 * 3600.0
    snap = Snapshot(
        "warm-up",
        t,
        (Rider(RiderId("r"), a, b, t),),
        (
            Taxi(TaxiId("i"), a, True, True),
            Taxi(TaxiId("j"), b, True, True),
            Taxi(TaxiId("o"), a, False, True),
        ),
    )
    decide(city, CountsView({}), snap, [Task(TaskId("k"), b, t)])
