"""One decision epoch: the three-step priority matching and Algorithm 2 (paper Section 4, docs/METHOD.md
sections 4-6).

``decide`` is the single pure entry point: (city, counts, snapshot, tasks) -> Decision. It reads as the
method does, one call per step:

1. the pickups (taxi-rider pairs within the radius) and the riders' trips (``services.matching.legs``);
2. Step 1, instrumented taxis x riders for sensing gain (``services.matching.steps.step1_sensing_matches``);
3. Step 2, ordinary taxis x the riders left (``services.matching.steps.step2_regular_matches``);
4. Step 3, free instrumented taxis x open POIs (``services.routing.step3.step3_monitoring_routes``);
5. Algorithm 2, the Step 3 routes improved together (``services.routing.algorithm2.improve_routes``);
6. the tasks the planned paths reach, and the decision's assembly.

Every assignment is exact (``services.matching.assignment``): gains in fixed point whose sums are exact,
waits in whole microseconds (the searches' own cost), phi to 2**-40 of the largest. Every path is the
canonical shortest path of its cost (``services.network.graph``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.epoch import Epoch
from services.ledger import Ledger, apply_decision, ledger_view
from services.matching.legs import Leg, Pickups, pickups, trips
from services.matching.steps import Match, Step1, select, step1_sensing_matches, step2_regular_matches
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
from services.network import hierarchy
from services.network.graph import RoadGraph, road_graph
from services.network.pads import pads_for
from services.routing.algorithm1 import Route
from services.routing.algorithm2 import improve_routes
from services.routing.step3 import Step3, step3_monitoring_routes
from services.sensing.gains import Counted, counted_csr, counted_rows, path_facts
from services.tasks import PlannedPath, Reach, apply_reaches, due_completions, reaches

__all__ = ["decide", "warm_up", "path_nodes", "INITIAL_SLOTS"]

INITIAL_SLOTS = 3
"""Intervals (from the epoch's own) whose gains are tabulated first; more are added if a path needs them."""


@dataclass(frozen=True, slots=True)
class _Present:
    """Who the epoch serves: the riders still waiting (those past their patience expire), the vacant taxis
    (instrumented first: taxi indices below ``len(instrumented)`` are instrumented)."""

    riders: list[Rider]
    expired: tuple[RiderId, ...]
    instrumented: list[Taxi]
    ordinary: list[Taxi]

    @property
    def taxis(self) -> list[Taxi]:
        return self.instrumented + self.ordinary


@dataclass(frozen=True, slots=True)
class _Riders:
    """Steps 1-2 put together: the matched pairs (Step 1's first), each pair's index among the pickups, its
    path (pickup leg then trip) and Step 1's paths as planned paths (the sensing taxis' commitments)."""

    step1: Step1
    step2: list[Match]
    at: NDArray[np.int64]
    paths: list[NDArray[np.int64]]
    planned: list[PlannedPath]

    @property
    def both(self) -> list[Match]:
        return self.step1.pairs + self.step2


@dataclass(frozen=True, slots=True)
class _Targets:
    """Step 3's POIs: the open tasks no Step 1 path reaches, by node (the first task at a node, in schedule
    order, stands for the node), and the nodes of the pending tasks (the ones a path can reach)."""

    open_tasks: list[Task]
    by_node: dict[int, TaskId]
    pending_nodes: NDArray[np.bool_]

    @property
    def nodes(self) -> NDArray[np.int64]:
        return np.fromiter(self.by_node, dtype=np.int64, count=len(self.by_node))


@dataclass(frozen=True, slots=True)
class _Monitoring:
    """Step 3 after Algorithm 2: the matched taxis and their routes, the joint utility after the initial
    matching and each accepted re-plan, Algorithm 2's passes and the interval slots tabulated."""

    taxis: list[Taxi]
    routes: list[Route]
    history: list[float]
    passes: int
    n_slots: int


@dataclass(frozen=True, slots=True)
class _Assembled:
    """The decision's matches, assignments and visits, and every planned path (for the tasks they reach)."""

    matches: list[RiderMatch]
    assignments: list[TaskAssignment]
    visits: list[Visit]
    planned: list[PlannedPath]


def path_nodes(graph: RoadGraph, start: int, edges: NDArray[np.int64]) -> tuple[int, ...]:
    """Node sequence of a path given its start node and edges."""
    if len(edges) == 0:
        return (int(start),)
    return (int(graph.edges.tail[edges[0]]), *graph.edges.head[edges].tolist())


def _present(snapshot: Snapshot, patience_s: float) -> _Present:
    """The riders within their patience and the vacant taxis of ``snapshot``."""
    now = snapshot.time_s
    expired = tuple(r.id for r in snapshot.riders if now - r.requested_at_s > patience_s)
    expired_set = set(expired)
    riders = [r for r in snapshot.riders if r.id not in expired_set]
    vacant = [t for t in snapshot.taxis if t.vacant]
    instr = [t for t in vacant if t.instrumented]
    ordinary = [t for t in vacant if not t.instrumented]
    return _Present(riders, tuple(RiderId(r) for r in expired), instr, ordinary)


def _pickups(ep: Epoch, who: _Present) -> Pickups:
    """Every (taxi, rider) pair whose fastest pickup path is within the radius."""
    net = ep.city.network
    xy = np.column_stack((net.x_m, net.y_m))
    origins = np.array([r.origin for r in who.riders], dtype=np.int64)
    taxi_nodes = np.array([t.node for t in who.taxis], dtype=np.int64)
    return pickups(ep.graph, xy, origins, taxi_nodes, ep.city.params.radius_m, ep.workers, ep.pads)


def _trips(ep: Epoch, riders: list[Rider], pk: Pickups) -> list[Leg]:
    """Each rider's service leg (pickup -> dropoff); an empty leg for a rider no taxi can pick up."""
    has_pair = np.zeros(len(riders), dtype=bool)
    has_pair[pk.rider] = True
    rows = np.flatnonzero(has_pair)
    legs = trips(ep.graph, [(riders[j].origin, riders[j].destination) for j in rows], ep.workers, ep.pads)
    service: list[Leg] = [Leg(np.zeros(0, dtype=np.int64), 0.0, 0.0)] * len(riders)
    for j, leg in zip(rows.tolist(), legs, strict=True):
        service[j] = leg
    return service


def _rider_paths(
    ep: Epoch, who: _Present, pk: Pickups, s1: Step1, s2: list[Match], service: Sequence[Leg]
) -> _Riders:
    """The matched riders' paths: the pickup leg (searched again for the matched pairs only) then the trip."""
    taxis, riders = who.taxis, who.riders
    both = s1.pairs + s2
    pair_keys = pk.rider * len(taxis) + pk.taxi  # ascending: the pairs are ordered by rider, then taxi
    at = np.searchsorted(pair_keys, np.array([j * len(taxis) + i for i, j, _ in both], dtype=np.int64))
    with ep.pads.take() as pad:
        legs_in = hierarchy.fastest_paths(
            ep.graph,
            pad,
            np.array([taxis[i].node for i, _, _ in both], dtype=np.int64),
            np.array([riders[j].origin for _, j, _ in both], dtype=np.int64),
        )
    paths = [
        np.concatenate((leg, service[j].edges)).astype(np.int64)
        for leg, (_, j, _) in zip(legs_in, both, strict=True)
    ]
    planned = [
        PlannedPath(taxis[i].id, taxis[i].node, edges, ep.now)
        for (i, _, _), edges in zip(s1.pairs, paths[: len(s1.pairs)], strict=True)
    ]
    return _Riders(s1, s2, at, paths, planned)


def _touching(graph: RoadGraph, paths: Sequence[PlannedPath], nodes: NDArray[np.bool_]) -> list[PlannedPath]:
    """The paths that pass through at least one of ``nodes`` (in order): the only ones ``tasks.reaches`` can
    find a pending task on, so it is given only these."""
    head = graph.edges.head
    return [p for p in paths if nodes[p.start] or bool(nodes[head[p.edges]].any())]


def _targets(ep: Epoch, tasks: Sequence[Task], planned: Sequence[PlannedPath]) -> _Targets:
    """Step 3's POIs: the open tasks not already reached by a Step 1 path, grouped by node."""
    pending_nodes = np.zeros(ep.city.network.n_nodes, dtype=bool)
    pending_nodes[[t.node for t in tasks if t.status == "pending"]] = True
    passive1 = reaches(ep.city, _touching(ep.graph, planned, pending_nodes), tasks)
    open_tasks = sorted(
        (t for t in tasks if t.is_open(ep.now) and t.id not in passive1),
        key=lambda t: (t.scheduled_at_s, t.id),
    )
    by_node: dict[int, TaskId] = {}
    for t in open_tasks:
        by_node.setdefault(t.node, t.id)
    return _Targets(open_tasks, by_node, pending_nodes)


def _algorithm2(ep: Epoch, free: Sequence[Taxi], counted_free: Counted, s3: Step3) -> _Monitoring:
    """Algorithm 2 over Step 3's matched taxis (``counted_free``: the free taxis' counted pairs)."""
    matched = [free[i] for i, _, _ in s3.pairs]
    counted = counted_rows(counted_free, [i for i, _, _ in s3.pairs])
    routes, history, passes = improve_routes(
        ep,
        [t.id for t in matched],
        counted,
        [r for _, r, _ in s3.pairs],
        [f for _, _, f in s3.pairs],
        s3.n_slots,
    )
    return _Monitoring(matched, routes, history, passes, s3.n_slots)


class _Facts:
    """The G-routes and timed G-routes of every planned path (riders' paths, then routes), in one compiled
    call; ``cells_of(q)`` and ``visits_of(q, taxi)`` read path ``q``'s."""

    def __init__(self, ep: Epoch, paths: Sequence[NDArray[np.int64]]) -> None:
        city = ep.city
        ptr = np.zeros(len(paths) + 1, dtype=np.int64)
        ptr[1:] = np.cumsum([len(e) for e in paths])
        flat = np.concatenate(paths).astype(np.int64) if paths else np.zeros(0, dtype=np.int64)
        self.cell_ptr, self.cells, self.pair_ptr, self.pair_k, self.pair_c = path_facts(
            ep.graph.edges,
            ptr,
            flat,
            ep.now,
            city.horizon.shift_s(ep.now),
            float(city.horizon.interval_s),
            city.grid.n_cells,
        )
        self.n_cols = city.grid.n_cols
        self.visited = ep.counts.visited

    def cells_of(self, q: int) -> tuple[tuple[int, int], ...]:
        n_cols, cells = self.n_cols, self.cells
        return tuple(
            (c % n_cols, c // n_cols) for c in cells[self.cell_ptr[q] : self.cell_ptr[q + 1]].tolist()
        )

    def visits_of(self, q: int, taxi: Taxi) -> list[Visit]:
        seen = self.visited.get(taxi.id, frozenset())
        ks = self.pair_k[self.pair_ptr[q] : self.pair_ptr[q + 1]].tolist()
        cs = self.pair_c[self.pair_ptr[q] : self.pair_ptr[q + 1]].tolist()
        return [Visit(taxi.id, IntervalKey(k), c) for k, c in zip(ks, cs, strict=True) if (k, c) not in seen]


def _rider_matches(
    ep: Epoch, who: _Present, pk: Pickups, rides: _Riders, service: Sequence[Leg], facts: _Facts
) -> tuple[list[RiderMatch], list[Visit]]:
    """Steps 1-2's rider matches and the visits Step 1's sensing taxis make on their way."""
    taxis, n1 = who.taxis, len(rides.step1.pairs)
    matches: list[RiderMatch] = []
    visits: list[Visit] = []
    for q, (i, j, gain) in enumerate(rides.both):
        k = int(rides.at[q])
        taxi, svc = taxis[i], service[j]
        matches.append(
            RiderMatch(
                1 if q < n1 else 2,
                taxi.id,
                who.riders[j].id,
                float(pk.length_m[k]),
                float(pk.wait_s[k]),
                svc.length_m,
                svc.time_s,
                gain,
                path_nodes(ep.graph, taxi.node, rides.paths[q]),
                facts.cells_of(q),
            )
        )
        if q < n1:
            visits.extend(facts.visits_of(q, taxi))
    return matches, visits


def _assemble(
    ep: Epoch,
    who: _Present,
    pk: Pickups,
    rides: _Riders,
    service: Sequence[Leg],
    mon: _Monitoring,
    by_node: dict[int, TaskId],
) -> _Assembled:
    """The rider matches, the task assignments, the visits to count and every planned path of the epoch."""
    facts = _Facts(ep, [*rides.paths, *(r.edges for r in mon.routes)])
    matches, visits = _rider_matches(ep, who, pk, rides, service, facts)
    p = ep.city.params
    planned = list(rides.planned)
    assignments: list[TaskAssignment] = []
    for q, (taxi, route) in enumerate(zip(mon.taxis, mon.routes, strict=True), start=len(rides.paths)):
        task_id = by_node[route.target]
        assignments.append(
            TaskAssignment(
                taxi.id,
                task_id,
                path_nodes(ep.graph, taxi.node, route.edges),
                facts.cells_of(q),
                route.length_m,
                route.time_s,
                route.gain,
                route.efficiency,
                p.unit_cost_cny_per_km * route.length_m / 1000.0,
                route.kappa,
            )
        )
        planned.append(PlannedPath(taxi.id, taxi.node, route.edges, ep.now, target_task=task_id))
        visits.extend(facts.visits_of(q, taxi))
    return _Assembled(matches, assignments, visits, planned)


def _task_updates(
    ep: Epoch, tasks: Sequence[Task], planned: Sequence[PlannedPath], pending_nodes: NDArray[np.bool_]
) -> tuple[dict[TaskId, Reach], tuple[Task, ...]]:
    """The tasks the planned paths reach and every task the epoch changes (due completions, then reaches)."""
    found = reaches(ep.city, _touching(ep.graph, planned, pending_nodes), tasks)
    updates = {t.id: t for t in due_completions(tasks, ep.now)}
    updates.update({t.id: t for t in apply_reaches(tasks, found, ep.now)})
    return found, tuple(updates.values())


def _stats(
    ep: Epoch,
    snapshot: Snapshot,
    who: _Present,
    rides: _Riders,
    out: _Assembled,
    targets: _Targets,
    found: dict[TaskId, Reach],
    mon: _Monitoring,
) -> dict[str, float | int]:
    """The decision's per-step diagnostics."""
    s1, history = rides.step1, mon.history
    return {
        "interval": ep.k0,
        "riders": len(snapshot.riders),
        "riders_expired": len(who.expired),
        "vacant_instrumented": len(who.instrumented),
        "vacant_ordinary": len(who.ordinary),
        "step1_matches": len(s1.pairs),
        "step2_matches": len(rides.step2),
        "step3_assignments": len(out.assignments),
        "step1_sensing_gain": float(sum(g for _, _, g in s1.pairs)),
        "total_wait_s": float(sum(m.wait_s for m in out.matches)),
        "open_tasks": len(targets.open_tasks),
        "passive_reaches": sum(1 for r in found.values() if r.mode == "passive"),
        "alg2_passes": mon.passes,
        "alg2_utility_initial": history[0] if history else 0.0,
        "alg2_utility_final": history[-1] if history else 0.0,
        "monitoring_cost_cny": float(sum(a.cost_cny for a in out.assignments)),
        **s1.stats,
    }


def _decision(
    ep: Epoch,
    snapshot: Snapshot,
    who: _Present,
    rides: _Riders,
    out: _Assembled,
    task_updates: tuple[Task, ...],
    stats: dict[str, float | int],
    n_slots: int,
) -> Decision:
    """The decision: the riders left unmatched, the completed tasks and the intervals touched (the tabulated
    slots and every visit's) beside the matches, assignments and visits."""
    taken = {j for _, j, _ in rides.both}
    riders = who.riders
    touched = sorted({IntervalKey(ep.k0 + s) for s in range(n_slots)} | {v.interval for v in out.visits})
    return Decision(
        epoch_id=snapshot.epoch_id,
        time_s=ep.now,
        rider_matches=tuple(out.matches),
        task_assignments=tuple(out.assignments),
        tasks_completed=tuple(t for t in task_updates if t.status == "completed"),
        task_updates=task_updates,
        unmatched_rider_ids=tuple(riders[j].id for j in range(len(riders)) if j not in taken),
        expired_rider_ids=who.expired,
        visits=tuple(dict.fromkeys(out.visits)),
        intervals_touched=tuple(touched),
        stats=stats,
    )


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
    lap = phase or (lambda _name: None)
    graph = road_graph(city)
    ep = Epoch(
        city,
        graph,
        counts,
        snapshot.time_s,
        int(city.horizon.interval_of(snapshot.time_s)),
        workers,
        pads_for(graph),
    )
    who = _present(snapshot, city.params.patience_s)
    pk = _pickups(ep, who)
    lap("pickups")
    service = _trips(ep, who.riders, pk)
    lap("trips")
    counted_instr = counted_csr(counts.visited, [t.id for t in who.instrumented], ep.k0)  # row i: taxi i
    s1 = step1_sensing_matches(
        ep, counted_instr, select(pk, pk.taxi < len(who.instrumented)), service, INITIAL_SLOTS
    )
    lap("step1")
    s2 = step2_regular_matches(pk, len(who.instrumented), {j for _, j, _ in s1.pairs}, len(who.riders))
    rides = _rider_paths(ep, who, pk, s1, s2, service)
    lap("step2")
    targets = _targets(ep, tasks, rides.planned)
    busy = {i for i, _, _ in s1.pairs}
    free_rows = [i for i in range(len(who.instrumented)) if i not in busy]
    free = [who.instrumented[i] for i in free_rows]
    mon = _Monitoring([], [], [], 0, s1.n_slots)
    if city.params.active_sensing and free and len(targets.by_node):
        counted_free = counted_rows(counted_instr, free_rows)
        s3 = step3_monitoring_routes(ep, free, counted_free, targets.nodes, s1.n_slots)
        lap("step3")
        mon = _algorithm2(ep, free, counted_free, s3)
        lap("algorithm2")
    out = _assemble(ep, who, pk, rides, service, mon, targets.by_node)
    found, task_updates = _task_updates(ep, tasks, out.planned, targets.pending_nodes)
    lap("tasks")
    return _decision(
        ep,
        snapshot,
        who,
        rides,
        out,
        task_updates,
        _stats(ep, snapshot, who, rides, out, targets, found, mon),
        mon.n_slots,
    )


def warm_up(city: City) -> None:
    """Solve a few tiny seeded epochs on ``city`` so that every compiled kernel a real epoch calls is compiled
    (or loaded from numba's on-disk cache), and the city's search structures (``road_graph``,
    ``search.landmarks``, the contraction hierarchy of ``services.network.hierarchy``) built, before the first
    real request: a kernel first met in a real epoch would
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
