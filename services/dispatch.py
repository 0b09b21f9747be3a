"""One decision epoch: the three-step priority matching and Algorithm 2 (docs/METHOD.md sections 4-6).

``decide`` is the single pure entry point: (city, counts, snapshot, tasks) -> Decision.

1. Step 1 (Eq. 4-7): vacant instrumented taxis x waiting riders within the pickup radius; a pair's weight is
   the marginal sensing gain of the service leg (pickup -> dropoff) for that taxi, leaving when it reaches
   the rider; pairs with a positive gain only; maximize the total gain, then minimize the total wait.
2. Step 2 (Eq. 8-11): vacant ordinary taxis x the remaining riders; maximize matches, then minimize wait.
3. Step 3 (Eq. 13-16): vacant instrumented taxis still free x open POIs (grouped by node); maximize
   matches, then the total phi of the enhanced A* routes (Algorithm 1); then Algorithm 2.

Every assignment is exact (``services.matching.assignment``): gains in fixed point whose sums are exact,
waits in whole microseconds (the searches' own cost), phi to 2**-40 of the largest. Every path is the
canonical shortest path of its cost (``services.network.graph``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.kernel.parallel import parallel_map
from services.ledger import Ledger, apply_decision, ledger_view
from services.matching.assignment import lexicographic_assignment
from services.matching.legs import Leg, pickups, trips
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
    TaxiId,
    Visit,
)
from services.network import search
from services.network.graph import INF, US_PER_S, RoadGraph, road_graph
from services.network.pads import Pads, pads_for
from services.routing.algorithm1 import Drive, Route, plan_routes, route_pair
from services.routing.algorithm2 import improve_routes
from services.sensing.gains import (
    Counted,
    Gains,
    counted_csr,
    counted_rows,
    eval_pairs,
    fixed_point_unit,
    gain_table,
    pair_gains_q,
    path_facts,
)
from services.tasks import PlannedPath, apply_reaches, due_completions, reaches

__all__ = ["decide", "warm_up", "step3_reach", "step3_reach_us", "path_nodes", "INITIAL_SLOTS", "PHI_BITS"]

INITIAL_SLOTS = 3
"""Intervals (from the epoch's own) whose gains are tabulated first; more are added if a path needs them."""

PHI_BITS = 40
"""Step 3 compares phi in units of 2**-40 of the largest."""


class _Epoch(NamedTuple):
    """What every step of one epoch shares: its time, its interval, the slots tabulated so far, the threads
    and Step 3's reach (whole microseconds)."""

    now: float
    k0: int
    n_slots: int
    workers: int
    reach_us: int


def path_nodes(graph: RoadGraph, start: int, edges: NDArray[np.int64]) -> tuple[int, ...]:
    """Node sequence of a path given its start node and edges."""
    if len(edges) == 0:
        return (int(start),)
    return (int(graph.edges.tail[edges[0]]), *graph.edges.head[edges].tolist())


def _step1(
    city: City,
    graph: RoadGraph,
    counts: CountsView,
    now: float,
    k0: int,
    counted: Counted,
    pick_taxi: NDArray[np.int64],
    pick_rider: NDArray[np.int64],
    pick_wait_s: NDArray[np.float64],
    pick_wait_us: NDArray[np.int64],
    service: Sequence[Leg],
    n_slots: int,
) -> tuple[list[tuple[int, int, float]], int, dict[str, float | int]]:
    """Step 1: (taxi index, rider index, gain) of the matched pairs, the slots needed, diagnostics."""
    stats: dict[str, float | int] = {"step1_candidates": len(pick_taxi)}
    if len(pick_taxi) == 0:
        return [], n_slots, stats
    ed = graph.edges
    leg_ptr = np.zeros(len(service) + 1, dtype=np.int64)
    leg_ptr[1:] = np.cumsum([len(leg.edges) for leg in service])
    leg_edges = np.concatenate([leg.edges for leg in service]).astype(np.int64) if service else leg_ptr[:0]
    crossings = max(int((ed.ec_ptr[leg.edges + 1] - ed.ec_ptr[leg.edges]).sum()) for leg in service)
    depart = now + pick_wait_s
    while True:
        top = gain_table(city, counts.counts, k0, n_slots, now)
        unit = fixed_point_unit(float(top.term.max(initial=0.0)), crossings)
        gn = gain_table(city, counts.counts, k0, n_slots, now, unit=unit)
        gq, max_slot = pair_gains_q(ed, gn, counted, pick_taxi, pick_rider, depart, leg_ptr, leg_edges)
        if max_slot < n_slots:
            break
        n_slots = int(max_slot) + 1
    ok = np.flatnonzero(gq > 0)  # a pair is a candidate for gain when its exact gain is positive
    sol = lexicographic_assignment(
        pick_taxi[ok], pick_rider[ok], gq[ok], pick_wait_us[ok], secondary_sense="min"
    )
    stats.update({"step1_positive_pairs": len(ok), "step1_gain_unit": gn.unit})
    chosen = ok[sol.pair]
    # the reported gain: the floating-point sum along the path, for the matched pairs only
    g, _gq, _ms = eval_pairs(
        ed, gn, counted, pick_taxi[chosen], pick_rider[chosen], depart[chosen], leg_ptr, leg_edges
    )
    out = [(int(pick_taxi[k]), int(pick_rider[k]), float(x)) for k, x in zip(chosen, g, strict=True)]
    return out, n_slots, stats


def step3_reach_us(city: City, graph: RoadGraph) -> int:
    """Step 3's reach in whole microseconds (``INF``: every taxi is a candidate for every POI): the city's
    ``step3_reach_s`` on a network that takes longer than ``step3_reach_above_s`` to cross
    (``search.crossing_us``), none on a smaller one (docs/METHOD.md section 4, "Step 3 at scale")."""
    p = city.params
    if p.step3_reach_s is None or search.crossing_us(graph) <= p.step3_reach_above_s * US_PER_S:
        return INF
    return int(round(p.step3_reach_s * US_PER_S))


def step3_reach(city: City) -> tuple[float | None, float]:
    """Step 3's reach on ``city`` in seconds (None: every taxi is a candidate for every POI) and the time the
    network takes to cross (``search.crossing_us``), which decides whether the reach applies."""
    graph = road_graph(city)
    reach = step3_reach_us(city, graph)
    return (None if reach >= INF else reach / US_PER_S), search.crossing_us(graph) / US_PER_S


def _step3(
    city: City,
    graph: RoadGraph,
    counts: CountsView,
    free: Sequence[Taxi],
    counted: Counted,
    targets: NDArray[np.int64],
    epoch: _Epoch,
    pads: Pads,
) -> tuple[list[tuple[int, Route, NDArray[np.int64]]], Gains, int]:
    """Step 3 before Algorithm 2: (free-taxi index, route, fastest path to the same POI) per matched pair
    (``counted``: the free taxis' counted pairs, in their order). A pair is a candidate when the POI lies
    within the taxi's reach; maximize the matches, then the total phi."""
    sources = np.array([t.node for t in free], dtype=np.int64)
    kappas = city.params.kappas
    n_slots = epoch.n_slots
    while True:
        gn = gain_table(city, counts.counts, epoch.k0, n_slots, epoch.now)
        plans = plan_routes(
            graph,
            gn,
            counted,
            sources,
            targets,
            epoch.now,
            kappas,
            epoch.workers,
            pads,
            reach_us=epoch.reach_us,
        )
        if plans.max_slot < n_slots:
            break
        n_slots = plans.max_slot + 1
    phi = plans.phi
    top = float(phi.max(initial=0.0))
    phi_q = (
        np.rint(phi / (top / 2.0**PHI_BITS)).astype(np.int64) if top > 0 else np.zeros(phi.shape, np.int64)
    )
    rows, cols = np.nonzero(plans.candidate)
    sol = lexicographic_assignment(
        rows, cols, np.ones(len(rows), dtype=np.int64), phi_q[rows, cols], secondary_sense="max"
    )
    pairs = list(zip(sol.rows.tolist(), sol.cols.tolist(), strict=True))

    def routes(chunk: Sequence[tuple[int, int]]) -> list[tuple[int, Route, NDArray[np.int64]]]:
        out = []
        with pads.take() as pad:
            for i, j in chunk:
                q = int(plans.kappa_index[i, j])
                leg = Drive(i, int(sources[i]), int(targets[j]), int(plans.d0_us[i, j]))
                fastest = route_pair(graph, gn, counted, leg, kappas, 0, pad)
                edges = fastest if kappas[q] == 0.0 else route_pair(graph, gn, counted, leg, kappas, q, pad)
                gain, time_s, length_m = (
                    float(plans.gain[i, j]),
                    float(plans.time_s[i, j]),
                    float(plans.length_m[i, j]),
                )
                out.append(
                    (i, Route(leg.source, leg.target, kappas[q], edges, gain, time_s, length_m, 0), fastest)
                )
        return out

    out = parallel_map(routes, pairs, epoch.workers)
    return out, gn, n_slots


def _touching(graph: RoadGraph, paths: Sequence[PlannedPath], nodes: NDArray[np.bool_]) -> list[PlannedPath]:
    """The paths that pass through at least one of ``nodes`` (in order): the only ones ``tasks.reaches`` can
    find a pending task on, so it is given only these."""
    head = graph.edges.head
    return [p for p in paths if nodes[p.start] or bool(nodes[head[p.edges]].any())]


def decide(
    city: City,
    counts: CountsView,
    snapshot: Snapshot,
    tasks: Sequence[Task],
    *,
    workers: int = 1,
    phase: Callable[[str], None] | None = None,
) -> Decision:
    """Solve one epoch (docs/METHOD.md sections 4-6). Pure: reads nothing but its arguments, changes nothing.

    Parameters
    ----------
    city : the served city (network, grid, weights, parameters).
    counts : Lambda per interval and the (interval, cell) pairs each taxi is already counted in, as of the
        start of the epoch.
    snapshot : waiting riders and taxi states, resolved to node indices.
    tasks : the city's open monitoring tasks (pending or assigned; others are ignored).
    workers : threads for the independent searches (the decision does not depend on it).
    phase : called with a phase's name as each phase ends ("pickups", "trips", "step1", "step2",
        "step3", "algorithm2", "tasks"): a benchmark's stopwatch; the core reads no clock itself.

    Returns
    -------
    Decision with the rider matches of Steps 1-2, the monitoring routes of Step 3 (after Algorithm 2), the
    task updates, the visits to count on commit, and per-step diagnostics in ``stats``.
    """
    p = city.params
    graph = road_graph(city)
    lap = phase or (lambda _name: None)
    now = snapshot.time_s
    k0 = int(city.horizon.interval_of(now))
    expired = tuple(r.id for r in snapshot.riders if now - r.requested_at_s > p.patience_s)
    expired_set = set(expired)
    riders = [r for r in snapshot.riders if r.id not in expired_set]
    vacant = [t for t in snapshot.taxis if t.vacant]
    instr = [t for t in vacant if t.instrumented]
    ordinary = [t for t in vacant if not t.instrumented]
    taxis = instr + ordinary  # instrumented first: indices < len(instr) are instrumented
    net = city.network
    pads = pads_for(graph)
    xy = np.column_stack((net.x_m, net.y_m))
    pk = pickups(
        graph,
        xy,
        np.array([r.origin for r in riders], dtype=np.int64),
        np.array([t.node for t in taxis], dtype=np.int64),
        p.radius_m,
        workers,
        pads,
    )
    lap("pickups")
    has_pair = np.zeros(len(riders), dtype=bool)
    has_pair[pk.rider] = True
    legs = trips(
        graph, [(riders[j].origin, riders[j].destination) for j in np.flatnonzero(has_pair)], workers, pads
    )
    service: list[Leg] = [Leg(np.zeros(0, dtype=np.int64), 0.0, 0.0)] * len(riders)
    for j, leg in zip(np.flatnonzero(has_pair).tolist(), legs, strict=True):
        service[j] = leg
    lap("trips")
    n_slots = INITIAL_SLOTS

    # Step 1
    is_instr = pk.taxi < len(instr)
    counted_instr = counted_csr(counts.visited, [t.id for t in instr], k0)  # row i: instr[i]
    s1, n_slots, s1_stats = _step1(
        city,
        graph,
        counts,
        now,
        k0,
        counted_instr,
        pk.taxi[is_instr],
        pk.rider[is_instr],
        pk.wait_s[is_instr],
        pk.wait_us[is_instr],
        service,
        n_slots,
    )
    taken = {j for _, j, _ in s1}
    lap("step1")

    # Step 2: ordinary taxis x the riders left; maximize matches, then minimize wait
    left = np.array([j not in taken for j in range(len(riders))], dtype=bool)
    ok = (pk.taxi >= len(instr)) & left[pk.rider] if len(pk.rider) else np.zeros(0, dtype=bool)
    sol2 = lexicographic_assignment(
        pk.taxi[ok],
        pk.rider[ok],
        np.ones(int(ok.sum()), dtype=np.int64),
        pk.wait_us[ok],
        secondary_sense="min",
    )
    s2 = [(int(i), int(j), 0.0) for i, j in zip(sol2.rows.tolist(), sol2.cols.tolist(), strict=True)]
    taken.update(j for _, j, _ in s2)
    unmatched = tuple(riders[j].id for j in range(len(riders)) if j not in taken)
    # the matched riders' paths: pickup leg (searched again for the matched pairs only) + trip
    both = s1 + s2
    pair_keys = pk.rider * len(taxis) + pk.taxi  # ascending: the pairs are ordered by rider, then taxi
    at = np.searchsorted(pair_keys, np.array([j * len(taxis) + i for i, j, _ in both], dtype=np.int64))
    with pads.take() as pad:
        legs_in = search.fastest_paths(
            graph,
            pad.forward,
            np.array([taxis[i].node for i, _, _ in both], dtype=np.int64),
            np.array([riders[j].origin for _, j, _ in both], dtype=np.int64),
        )
    rider_paths = [
        np.concatenate((leg, service[j].edges)).astype(np.int64)
        for leg, (_, j, _) in zip(legs_in, both, strict=True)
    ]
    planned = [
        PlannedPath(taxis[i].id, taxis[i].node, edges, now)
        for (i, _, _), edges in zip(s1, rider_paths[: len(s1)], strict=True)
    ]
    busy_taxis = {i for i, _, _ in s1}
    lap("step2")

    # Step 3: open tasks not already reached by a Step 1 path, grouped by POI node
    task_nodes = np.zeros(net.n_nodes, dtype=bool)
    task_nodes[[t.node for t in tasks if t.status == "pending"]] = True
    passive1 = reaches(city, _touching(graph, planned, task_nodes), tasks)
    open_tasks = sorted(
        (t for t in tasks if t.is_open(now) and t.id not in passive1), key=lambda t: (t.scheduled_at_s, t.id)
    )
    by_node: dict[int, TaskId] = {}
    for t in open_tasks:
        by_node.setdefault(t.node, t.id)
    targets = np.fromiter(by_node, dtype=np.int64, count=len(by_node))
    free_rows = [i for i in range(len(instr)) if i not in busy_taxis]
    free = [instr[i] for i in free_rows]
    matched: list[Taxi] = []
    routes: list[Route] = []
    history: list[float] = []
    passes = 0
    if p.active_sensing and free and len(targets):
        counted_free = counted_rows(counted_instr, free_rows)
        epoch = _Epoch(now, k0, n_slots, workers, step3_reach_us(city, graph))
        s3, gn, n_slots = _step3(city, graph, counts, free, counted_free, targets, epoch, pads)
        lap("step3")
        matched = [free[i] for i, _, _ in s3]
        counted = counted_rows(counted_free, [i for i, _, _ in s3])
        routes, history, passes = improve_routes(
            city,
            graph,
            counts,
            [t.id for t in matched],
            counted,
            [r for _, r, _ in s3],
            [f for _, _, f in s3],
            now,
            k0,
            n_slots,
            workers,
            pads,
        )
        lap("algorithm2")

    # every planned path's G-route and timed G-route, in one compiled call
    all_paths = [*rider_paths, *(r.edges for r in routes)]
    ptr = np.zeros(len(all_paths) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(e) for e in all_paths])
    flat = np.concatenate(all_paths).astype(np.int64) if all_paths else np.zeros(0, dtype=np.int64)
    cell_ptr, cells, pair_ptr, pair_k, pair_c = path_facts(
        graph.edges,
        ptr,
        flat,
        now,
        city.horizon.shift_s(now),
        float(city.horizon.interval_s),
        city.grid.n_cells,
    )
    n_cols = city.grid.n_cols

    def cells_of(q: int) -> tuple[tuple[int, int], ...]:
        return tuple((c % n_cols, c // n_cols) for c in cells[cell_ptr[q] : cell_ptr[q + 1]].tolist())

    def visits_of(q: int, taxi: Taxi) -> list[Visit]:
        seen = counts.visited.get(taxi.id, frozenset())
        ks = pair_k[pair_ptr[q] : pair_ptr[q + 1]].tolist()
        cs = pair_c[pair_ptr[q] : pair_ptr[q + 1]].tolist()
        return [Visit(taxi.id, IntervalKey(k), c) for k, c in zip(ks, cs, strict=True) if (k, c) not in seen]

    matches: list[RiderMatch] = []
    visits: list[Visit] = []
    for q, (i, j, gain) in enumerate(both):
        k = int(at[q])
        taxi, svc = taxis[i], service[j]
        matches.append(
            RiderMatch(
                1 if q < len(s1) else 2,
                taxi.id,
                riders[j].id,
                float(pk.length_m[k]),
                float(pk.wait_s[k]),
                svc.length_m,
                svc.time_s,
                gain,
                path_nodes(graph, taxi.node, rider_paths[q]),
                cells_of(q),
            )
        )
        if q < len(s1):
            visits.extend(visits_of(q, taxi))
    assignments: list[TaskAssignment] = []
    for q, (taxi, route) in enumerate(zip(matched, routes, strict=True), start=len(rider_paths)):
        task_id = by_node[route.target]
        assignments.append(
            TaskAssignment(
                taxi.id,
                task_id,
                path_nodes(graph, taxi.node, route.edges),
                cells_of(q),
                route.length_m,
                route.time_s,
                route.gain,
                route.efficiency,
                p.unit_cost_cny_per_km * route.length_m / 1000.0,
                route.kappa,
            )
        )
        planned.append(PlannedPath(taxi.id, taxi.node, route.edges, now, target_task=task_id))
        visits.extend(visits_of(q, taxi))

    found = reaches(city, _touching(graph, planned, task_nodes), tasks)
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
        "step2_matches": len(s2),
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
    lap("tasks")
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
    """Solve a few tiny seeded epochs on ``city`` so that every compiled kernel a real epoch calls is compiled
    (or loaded from numba's on-disk cache), and the city's search structures (``road_graph``,
    ``search.landmarks``) built, before the first real request: a kernel first met in a real epoch would
    otherwise be compiled inside it (seconds on a fresh install). The epochs cover riders matched in Steps 1
    and 2, Step 3 from the POIs' side (fewer than half as many POIs as taxis) with taxis counted in cells
    (their own costs, goal-directed searches) and from the taxis' side, and Algorithm 2's re-plans, on one
    thread and on two (``tests/unit/test_warm_up.py`` checks that later epochs compile nothing new)."""
    rng = np.random.default_rng(7)
    n = city.network.n_nodes
    hz = city.horizon  # a minute into a day's first interval of the horizon, where cells have a gain
    t0 = hz.interval_start_s(IntervalKey(19_877 * hz.per_day)) + 60.0  # 2024-06-03
    instrumented = [int(x) for x in rng.integers(n, size=10)]
    ordinary = [int(x) for x in rng.integers(n, size=3)]
    taxis = tuple(Taxi(TaxiId(f"i{j}"), v, True, True) for j, v in enumerate(instrumented)) + tuple(
        Taxi(TaxiId(f"o{j}"), v, False, True) for j, v in enumerate(ordinary)
    )
    ledger = Ledger()
    for e, (new_tasks, workers) in enumerate(((2, 1), (2, 2), (12, 2))):
        t = t0 + e * hz.epoch_s
        # riders at taxis' nodes so that there are matches (one at an instrumented taxi, three at ordinary)
        riders = tuple(
            Rider(RiderId(f"r{e}-{j}"), v, int(rng.integers(n)), t)
            for j, v in enumerate((instrumented[e], ordinary[0], ordinary[1], ordinary[2]))
        )
        for j in range(new_tasks):
            ledger.tasks[TaskId(f"k{e}-{j}")] = Task(TaskId(f"k{e}-{j}"), int(rng.integers(n)), t)
        view = ledger_view(ledger, (taxi.id for taxi in taxis if taxi.instrumented), city.grid.n_cells)
        snap = Snapshot(f"warm-up-{e}", t, riders, taxis)
        d = decide(city, view, snap, list(ledger.tasks.values()), workers=workers)
        apply_decision(ledger, d.visits, d.task_updates)
