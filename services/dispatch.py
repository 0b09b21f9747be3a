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

import dataclasses
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

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
from services.network.scratch import scratch_pool
from services.routing.algorithm1 import Route
from services.routing.algorithm2 import improve_routes
from services.routing.step3 import step3_monitoring_routes
from services.sensing.gains import Counted, counted_csr, counted_rows, path_facts
from services.tasks import PlannedPath, Reach, apply_reaches, due_completions, reaches

__all__ = ["decide", "warm_up", "path_nodes", "INITIAL_SLOTS"]

INITIAL_SLOTS = 3
"""Intervals (from the epoch's own) whose gains are tabulated first; more are added if a path needs them."""


@dataclass(frozen=True, slots=True)
class _Ride:
    """A rider matched in Step 1 (an instrumented taxi) or Step 2 (an ordinary one): the taxi and the rider,
    the reported sensing gain, the pickup leg's length and wait, the trip, and the planned path (the pickup
    leg then the trip)."""

    step: Literal[1, 2]
    taxi: Taxi
    rider: Rider
    gain: float
    pickup_m: float
    wait_s: float
    trip: Leg
    edges: NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class _Routed:
    """A free instrumented taxi sent to a POI in Step 3 (its route after Algorithm 2) and the task the POI
    stands for."""

    taxi: Taxi
    route: Route
    task_id: TaskId


@dataclass(slots=True)
class _Tally:
    """One epoch's decision as the steps build it, in their order.

    Who the epoch serves: the riders still waiting (those past their patience expire) and the vacant taxis,
    instrumented and ordinary; each rider's trip (pickup -> dropoff). Steps 1-2: the rides (Step 1's
    first), Step 1's diagnostics and the interval slots tabulated so far. Step 3's POIs: the open tasks no
    Step 1 path reaches, by node (the first task at a node, in schedule order, stands for the node), and the
    nodes of the pending tasks (the only ones a path can reach). Step 3 after Algorithm 2: the routed taxis,
    the joint utility after the initial matching and each accepted re-plan, Algorithm 2's passes. Last,
    what the decision reports: the rider matches, the task assignments, the visits to count and every
    planned path (for the tasks they reach).
    """

    riders: list[Rider]
    expired: tuple[RiderId, ...]
    instrumented: list[Taxi]
    ordinary: list[Taxi]
    trips: list[Leg] = field(default_factory=list)
    rides: list[_Ride] = field(default_factory=list)
    step1_stats: dict[str, float | int] = field(default_factory=dict)
    n_slots: int = INITIAL_SLOTS
    open_tasks: list[Task] = field(default_factory=list)
    by_node: dict[int, TaskId] = field(default_factory=dict)
    pending_nodes: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    routed: list[_Routed] = field(default_factory=list)
    history: list[float] = field(default_factory=list)
    passes: int = 0
    matches: list[RiderMatch] = field(default_factory=list)
    assignments: list[TaskAssignment] = field(default_factory=list)
    visits: list[Visit] = field(default_factory=list)
    planned: list[PlannedPath] = field(default_factory=list)


def path_nodes(graph: RoadGraph, start: int, edges: NDArray[np.int64]) -> tuple[int, ...]:
    """Node sequence of a path given its start node and edges."""
    if len(edges) == 0:
        return (int(start),)
    return (int(graph.edges.tail[edges[0]]), *graph.edges.head[edges].tolist())


def _present(snapshot: Snapshot, patience_s: float) -> _Tally:
    """The riders within their patience and the vacant taxis of ``snapshot``."""
    now = snapshot.time_s
    expired = tuple(r.id for r in snapshot.riders if now - r.requested_at_s > patience_s)
    expired_set = set(expired)
    riders = [r for r in snapshot.riders if r.id not in expired_set]
    vacant = [t for t in snapshot.taxis if t.vacant]
    instr = [t for t in vacant if t.instrumented]
    ordinary = [t for t in vacant if not t.instrumented]
    return _Tally(riders, tuple(RiderId(r) for r in expired), instr, ordinary)


def _pickups(epoch: Epoch, tally: _Tally) -> tuple[Pickups, Pickups]:
    """Every (taxi, rider) pair whose fastest pickup path is within the radius: the instrumented taxis'
    pairs and the ordinary taxis' (a pair's taxi is its index among its own kind). One search for both."""
    net = epoch.city.network
    xy = np.column_stack((net.x_m, net.y_m))
    origins = np.array([r.origin for r in tally.riders], dtype=np.int64)
    fleet = tally.instrumented + tally.ordinary
    taxi_nodes = np.array([t.node for t in fleet], dtype=np.int64)
    pk = pickups(epoch.graph, xy, origins, taxi_nodes, epoch.city.params.radius_m, epoch.workers, epoch.pool)
    n = len(tally.instrumented)
    ordinary = select(pk, pk.taxi >= n)
    return select(pk, pk.taxi < n), dataclasses.replace(ordinary, taxi=ordinary.taxi - n)


def _trips(epoch: Epoch, riders: list[Rider], cands: Sequence[Pickups]) -> list[Leg]:
    """Each rider's service leg (pickup -> dropoff); an empty leg for a rider no taxi can pick up."""
    has_pair = np.zeros(len(riders), dtype=bool)
    for pk in cands:
        has_pair[pk.rider] = True
    rows = np.flatnonzero(has_pair)
    legs = trips(
        epoch.graph, [(riders[j].origin, riders[j].destination) for j in rows], epoch.workers, epoch.pool
    )
    service: list[Leg] = [Leg(np.zeros(0, dtype=np.int64), 0.0, 0.0)] * len(riders)
    for j, leg in zip(rows.tolist(), legs, strict=True):
        service[j] = leg
    return service


def _rides(
    epoch: Epoch, tally: _Tally, sensing: Step1, regular: list[Match], cands: tuple[Pickups, Pickups]
) -> None:
    """Steps 1-2's rides: the pickup leg (searched again for the matched pairs only) then the trip (from
    ``tally``'s trips)."""
    steps: tuple[tuple[Literal[1, 2], list[Taxi], Pickups, list[Match]], ...] = (
        (1, tally.instrumented, cands[0], sensing.pairs),
        (2, tally.ordinary, cands[1], regular),
    )
    chosen = [(step, fleet[m.taxi], pk, m) for step, fleet, pk, matches in steps for m in matches]
    with epoch.pool.take() as scratch:
        legs_in = hierarchy.fastest_paths(
            epoch.graph,
            scratch,
            np.array([taxi.node for _, taxi, _, _ in chosen], dtype=np.int64),
            np.array([tally.riders[m.rider].origin for *_, m in chosen], dtype=np.int64),
        )
    for (step, taxi, pk, m), leg in zip(chosen, legs_in, strict=True):
        trip = tally.trips[m.rider]
        tally.rides.append(
            _Ride(
                step,
                taxi,
                tally.riders[m.rider],
                m.gain,
                float(pk.length_m[m.pickup]),
                float(pk.wait_s[m.pickup]),
                trip,
                np.concatenate((leg, trip.edges)).astype(np.int64),
            )
        )
    tally.step1_stats, tally.n_slots = sensing.stats, sensing.n_slots
    tally.planned = [
        PlannedPath(r.taxi.id, r.taxi.node, r.edges, epoch.now) for r in tally.rides if r.step == 1
    ]


def _touching(graph: RoadGraph, paths: Sequence[PlannedPath], nodes: NDArray[np.bool_]) -> list[PlannedPath]:
    """The paths that pass through at least one of ``nodes`` (in order): the only ones ``tasks.reaches`` can
    find a pending task on, so it is given only these."""
    head = graph.edges.head
    return [p for p in paths if nodes[p.start] or bool(nodes[head[p.edges]].any())]


def _targets(epoch: Epoch, tally: _Tally, tasks: Sequence[Task]) -> None:
    """Step 3's POIs: the open tasks not already reached by a Step 1 path, grouped by node."""
    pending_nodes = np.zeros(epoch.city.network.n_nodes, dtype=bool)
    pending_nodes[[t.node for t in tasks if t.status == "pending"]] = True
    passive1 = reaches(epoch.city, _touching(epoch.graph, tally.planned, pending_nodes), tasks)
    tally.open_tasks = sorted(
        (t for t in tasks if t.is_open(epoch.now) and t.id not in passive1),
        key=lambda t: (t.scheduled_at_s, t.id),
    )
    for t in tally.open_tasks:
        tally.by_node.setdefault(t.node, t.id)
    tally.pending_nodes = pending_nodes


def _monitoring(
    epoch: Epoch, tally: _Tally, counted: Counted, busy: set[int], lap: Callable[[str], None]
) -> None:
    """Step 3 and Algorithm 2 over the instrumented taxis Step 1 left free (``busy``: the ones it matched;
    row ``i`` of ``counted``: instrumented taxi ``i``'s counted pairs), when active sensing is on and there
    are free taxis and POIs."""
    free_rows = [i for i in range(len(tally.instrumented)) if i not in busy]
    free = [tally.instrumented[i] for i in free_rows]
    if not (epoch.city.params.active_sensing and free and tally.by_node):
        return
    counted_free = counted_rows(counted, free_rows)
    nodes = np.fromiter(tally.by_node, dtype=np.int64, count=len(tally.by_node))
    s3 = step3_monitoring_routes(epoch, free, counted_free, nodes, tally.n_slots)
    lap("step3")
    taxis = [free[i] for i in s3.taxis]
    routes, tally.history, tally.passes = improve_routes(
        epoch,
        [t.id for t in taxis],
        counted_rows(counted_free, s3.taxis),
        list(s3.routes),
        s3.fastest,
        s3.n_slots,
    )
    tally.routed = [_Routed(t, r, tally.by_node[r.target]) for t, r in zip(taxis, routes, strict=True)]
    tally.n_slots = s3.n_slots
    lap("algorithm2")


class _Facts:
    """The G-routes and timed G-routes of every planned path (riders' paths, then routes), in one compiled
    call; ``cells_of(q)`` and ``visits_of(q, taxi)`` read path ``q``'s."""

    def __init__(self, epoch: Epoch, paths: Sequence[NDArray[np.int64]]) -> None:
        city = epoch.city
        ptr = np.zeros(len(paths) + 1, dtype=np.int64)
        ptr[1:] = np.cumsum([len(e) for e in paths])
        flat = np.concatenate(paths).astype(np.int64) if paths else np.zeros(0, dtype=np.int64)
        self.cell_ptr, self.cells, self.pair_ptr, self.pair_k, self.pair_c = path_facts(
            epoch.graph.edges,
            ptr,
            flat,
            epoch.now,
            city.horizon.shift_s(epoch.now),
            float(city.horizon.interval_s),
            city.grid.n_cells,
        )
        self.rows, self.cols = np.divmod(self.cells, city.grid.n_cols)
        self.visited = epoch.counts.visited

    def cells_of(self, q: int) -> tuple[tuple[int, int], ...]:
        lo, hi = self.cell_ptr[q], self.cell_ptr[q + 1]
        return tuple(zip(self.cols[lo:hi].tolist(), self.rows[lo:hi].tolist(), strict=True))

    def visits_of(self, q: int, taxi: Taxi) -> list[Visit]:
        seen = self.visited.get(taxi.id, frozenset())
        ks = self.pair_k[self.pair_ptr[q] : self.pair_ptr[q + 1]].tolist()
        cs = self.pair_c[self.pair_ptr[q] : self.pair_ptr[q + 1]].tolist()
        return [Visit(taxi.id, IntervalKey(k), c) for k, c in zip(ks, cs, strict=True) if (k, c) not in seen]


def _assemble(epoch: Epoch, tally: _Tally) -> None:
    """The rider matches, the task assignments, the visits to count (Step 1's taxis', then the routed
    taxis') and every planned path of the epoch (Step 1's, then the routes)."""
    facts = _Facts(epoch, [*(r.edges for r in tally.rides), *(m.route.edges for m in tally.routed)])
    for q, ride in enumerate(tally.rides):
        tally.matches.append(
            RiderMatch(
                ride.step,
                ride.taxi.id,
                ride.rider.id,
                ride.pickup_m,
                ride.wait_s,
                ride.trip.length_m,
                ride.trip.time_s,
                ride.gain,
                path_nodes(epoch.graph, ride.taxi.node, ride.edges),
                facts.cells_of(q),
            )
        )
        if ride.step == 1:
            tally.visits.extend(facts.visits_of(q, ride.taxi))
    unit_cost = epoch.city.params.unit_cost_cny_per_km
    for q, m in enumerate(tally.routed, start=len(tally.rides)):
        taxi, route = m.taxi, m.route
        tally.assignments.append(
            TaskAssignment(
                taxi.id,
                m.task_id,
                path_nodes(epoch.graph, taxi.node, route.edges),
                facts.cells_of(q),
                route.length_m,
                route.time_s,
                route.gain,
                route.efficiency,
                unit_cost * route.length_m / 1000.0,
                route.kappa,
            )
        )
        tally.planned.append(PlannedPath(taxi.id, taxi.node, route.edges, epoch.now, target_task=m.task_id))
        tally.visits.extend(facts.visits_of(q, taxi))


def _task_updates(
    epoch: Epoch, tally: _Tally, tasks: Sequence[Task]
) -> tuple[dict[TaskId, Reach], tuple[Task, ...]]:
    """The tasks the planned paths reach and every task the epoch changes (due completions, then reaches)."""
    found = reaches(epoch.city, _touching(epoch.graph, tally.planned, tally.pending_nodes), tasks)
    updates = {t.id: t for t in due_completions(tasks, epoch.now)}
    updates.update({t.id: t for t in apply_reaches(tasks, found, epoch.now)})
    return found, tuple(updates.values())


def _stats(
    epoch: Epoch, snapshot: Snapshot, tally: _Tally, found: dict[TaskId, Reach]
) -> dict[str, float | int]:
    """The decision's per-step diagnostics."""
    history = tally.history
    by_step = Counter(m.step for m in tally.matches)  # Decision.matches_by_step reads these two counts
    return {
        "interval": epoch.k0,
        "riders": len(snapshot.riders),
        "riders_expired": len(tally.expired),
        "vacant_instrumented": len(tally.instrumented),
        "vacant_ordinary": len(tally.ordinary),
        "step1_matches": by_step[1],
        "step2_matches": by_step[2],
        "step3_assignments": len(tally.assignments),
        "step1_sensing_gain": float(sum(r.gain for r in tally.rides if r.step == 1)),
        "total_wait_s": float(sum(m.wait_s for m in tally.matches)),
        "open_tasks": len(tally.open_tasks),
        "passive_reaches": sum(1 for r in found.values() if r.mode == "passive"),
        "alg2_passes": tally.passes,
        "alg2_utility_initial": history[0] if history else 0.0,
        "alg2_utility_final": history[-1] if history else 0.0,
        "monitoring_cost_cny": float(sum(a.cost_cny for a in tally.assignments)),
        **tally.step1_stats,
    }


def _decision(
    epoch: Epoch,
    snapshot: Snapshot,
    tally: _Tally,
    task_updates: tuple[Task, ...],
    stats: dict[str, float | int],
) -> Decision:
    """The decision: the riders left unmatched, the completed tasks and the intervals touched (the tabulated
    slots and every visit's) beside the matches, assignments and visits."""
    taken = {ride.rider.id for ride in tally.rides}
    touched = sorted(
        {IntervalKey(epoch.k0 + s) for s in range(tally.n_slots)} | {v.interval for v in tally.visits}
    )
    return Decision(
        epoch_id=snapshot.epoch_id,
        time_s=epoch.now,
        rider_matches=tuple(tally.matches),
        task_assignments=tuple(tally.assignments),
        tasks_completed=tuple(t for t in task_updates if t.status == "completed"),
        task_updates=task_updates,
        unmatched_rider_ids=tuple(r.id for r in tally.riders if r.id not in taken),
        expired_rider_ids=tally.expired,
        visits=tuple(dict.fromkeys(tally.visits)),
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
    epoch = Epoch(
        city,
        graph,
        counts,
        snapshot.time_s,
        int(city.horizon.interval_of(snapshot.time_s)),
        workers,
        scratch_pool(graph),
    )
    tally = _present(snapshot, city.params.patience_s)
    instrumented, ordinary = _pickups(epoch, tally)
    lap("pickups")
    tally.trips = _trips(epoch, tally.riders, (instrumented, ordinary))
    lap("trips")
    counted = counted_csr(counts.visited, [t.id for t in tally.instrumented], epoch.k0)  # row i: taxi i
    sensing = step1_sensing_matches(epoch, counted, instrumented, tally.trips, INITIAL_SLOTS)
    lap("step1")
    regular = step2_regular_matches(ordinary, {m.rider for m in sensing.pairs}, len(tally.riders))
    _rides(epoch, tally, sensing, regular, (instrumented, ordinary))
    lap("step2")
    _targets(epoch, tally, tasks)
    _monitoring(epoch, tally, counted, {m.taxi for m in sensing.pairs}, lap)
    _assemble(epoch, tally)
    found, task_updates = _task_updates(epoch, tally, tasks)
    lap("tasks")
    return _decision(epoch, snapshot, tally, task_updates, _stats(epoch, snapshot, tally, found))


def warm_up(city: City) -> None:
    """Solve a few tiny seeded epochs on ``city`` so that every compiled kernel a real epoch calls is compiled
    (or loaded from numba's on-disk cache), and the city's search structures (``road_graph``,
    ``point_to_point.landmarks``, the contraction hierarchy of ``services.network.hierarchy``) built, before
    the first real request: a kernel first met in a real epoch would otherwise be compiled inside it (seconds
    on a fresh install). The epochs cover riders matched in Steps 1 and 2, Step 3 from the POIs' side (fewer
    than half as many POIs as taxis) with taxis counted in cells (their own costs, goal-directed searches) and
    from the taxis' side (enough of them to read the epoch's base costs, ``algorithm1.OVERLAY_TAXIS``), and
    Algorithm 2's re-plans, on one thread and on two (``tests/unit/test_warm_up.py``
    checks that later epochs compile nothing new)."""
    rng = np.random.default_rng(7)
    n = city.network.n_nodes
    hz = city.horizon  # a minute into a day's first interval of the horizon, where cells have a gain
    t0 = hz.interval_start_s(IntervalKey(19_877 * hz.per_day)) + 60.0  # 2024-06-03
    instrumented = [int(x) for x in rng.integers(n, size=16)]  # the last epoch: Step 3's Overlay too
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
