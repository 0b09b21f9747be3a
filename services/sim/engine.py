"""The fleet simulator: taxis, riders and POI tasks over one operating horizon (docs/METHOD.md sections 6
and 10).

Every epoch the simulator builds the snapshot the platform would post (waiting riders, every taxi's node
and state), asks a ``Dispatcher`` for the decision and applies it: matched taxis drive their path at the
network speed (busy until the drop-off), Step 3 taxis drive to their POI (vacant again from the epoch after
arrival), unmatched riders wait until their patience runs out, and vacant taxis with no job drift toward
cells of high recent request density. The dispatcher is the core in-process (``LocalDispatcher``) or a
running service over HTTP (``app.entrypoints.replay_client``): the simulator cannot tell them apart, so
for the same seed both give the same run.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from services.city import City, Horizon
from services.model import (
    IntervalKey,
    Rider,
    RiderId,
    Snapshot,
    Task,
    TaskAssignment,
    TaskId,
    Taxi,
    TaxiId,
)
from services.sim.demand import DemandSet, Request
from services.sim.drift import Drift, drift_map
from services.sim.local import Outcome

__all__ = [
    "SIM_VERSION",
    "Dispatcher",
    "SimConfig",
    "RiderRecord",
    "EpochRecord",
    "RunTrace",
    "Job",
    "poi_tasks",
    "simulate",
]

# Part of every cached run's key: bump it whenever a decision of the core can change, so no run simulated
# by older code is reused. 2: the rebuilt routing room (exact Step 1 at every size, canonical tie-breaks).
SIM_VERSION = "2"


class Dispatcher(Protocol):
    """Where decisions come from: the core in-process or a service over HTTP."""

    def add_tasks(self, tasks: Sequence[Task]) -> None: ...

    def epoch(self, snapshot: Snapshot) -> Outcome: ...

    def tasks(self) -> list[Task]: ...

    def interval_counts(self, k: IntervalKey) -> NDArray[np.int64]: ...


@dataclass(frozen=True, slots=True)
class SimConfig:
    """One simulation run (the city and the demand are passed separately).

    ``wait_only`` reports every taxi as ordinary, so every rider is matched on wait alone and nothing is
    sensed: the baseline of the price of sensing.
    """

    n_instrumented: int = 60
    n_ordinary: int = 60
    n_tasks: int = 85
    seed: int = 0
    drift: bool = True
    drift_window_s: float = 3600.0  # requests this recent make a cell attractive
    drift_radius_m: float = 3000.0  # how far (cell centre to centre) an idle taxi looks
    drift_rethink_s: float = 1800.0  # mean time an idle taxi stays at its target before looking again
    wait_only: bool = False
    id_prefix: str = ""  # prepended to taxi, rider and task ids (unique ids on a shared service)

    def __post_init__(self) -> None:
        if self.n_instrumented < 0 or self.n_ordinary < 0 or self.n_tasks < 0:
            raise ValueError("fleet sizes and task count must be non-negative")
        if self.drift_window_s <= 0 or self.drift_radius_m <= 0 or self.drift_rethink_s <= 0:
            raise ValueError("drift window, radius and rethink time must be positive")


@dataclass(slots=True)
class RiderRecord:
    """One posted request and what became of it."""

    id: RiderId
    requested_at_s: float
    matched_at_s: float | None = None
    step: int | None = None
    taxi_id: TaxiId | None = None
    pickup_s: float | None = None  # pickup travel time (the core's wait)
    left_at_s: float | None = None  # patience ran out

    @property
    def wait_s(self) -> float | None:
        """Request to pickup: time waiting to be matched plus the pickup drive."""
        if self.matched_at_s is None or self.pickup_s is None:
            return None
        return self.matched_at_s - self.requested_at_s + self.pickup_s


@dataclass(frozen=True, slots=True)
class EpochRecord:
    time_s: float
    waiting: int
    vacant_instrumented: int
    vacant_ordinary: int
    step1: int
    step2: int
    step3: int
    expired: int
    solve_ms: float


@dataclass(frozen=True, slots=True)
class RunTrace:
    """Everything a run produced; ``services.sim.kpi`` turns it into KPIs."""

    config: SimConfig
    demand: dict[str, object]  # the demand set's manifest
    start_s: float
    end_s: float
    epoch_s: int
    riders: tuple[RiderRecord, ...]
    tasks: tuple[Task, ...]  # as the dispatcher holds them after the last epoch
    assignments: tuple[tuple[float, TaskAssignment], ...]  # (epoch time, Step 3 route)
    counts: dict[IntervalKey, NDArray[np.int64]]  # Lambda per horizon interval after the last epoch
    epochs: tuple[EpochRecord, ...]
    n_unposted: int  # requests after the last epoch (not part of this run)


@dataclass(slots=True)
class Job:
    """A taxi's committed path: nodes and the time it is at each (the network's travel times from
    ``depart_s``); the taxi is at the path's last node, vacant again, once that time has come."""

    nodes: NDArray[np.int64]
    times: NDArray[np.float64]

    @classmethod
    def along(cls, city: City, path: Sequence[int], depart_s: float) -> Job:
        """The job of driving ``path`` from ``depart_s``."""
        nodes = np.asarray(path, dtype=np.int64)
        edges = city.network.edge_ids(nodes)
        return cls(nodes, depart_s + np.concatenate(([0.0], np.cumsum(city.network.edge_time_s[edges]))))

    def node_at(self, now: float) -> int:
        """The last node of the path reached by ``now`` (the first before departure)."""
        i = int(np.searchsorted(self.times, now, side="right")) - 1
        return int(self.nodes[max(i, 0)])

    def done_by(self, now: float) -> bool:
        """Whether the path's last node is reached by ``now``."""
        return bool(self.times[-1] <= now)


@dataclass(slots=True)
class _TaxiState:
    id: TaxiId
    instrumented: bool
    node: int
    job: Job | None = None
    target: int = -1  # drift hub row, -1 none
    at_target: bool = False


def poi_tasks(
    candidates: NDArray[np.int64],
    n: int,
    start_s: float,
    length_s: float,
    rng: np.random.Generator,
    prefix: str = "",
) -> list[Task]:
    """``n`` monitoring tasks at distinct candidate POI nodes, scheduled uniformly over the horizon
    (whole seconds, sorted), ids ``{prefix}poi00``...; fewer candidates than ``n`` is an error."""
    nodes = np.unique(np.asarray(candidates, dtype=np.int64))
    if n > nodes.size:
        raise ValueError(f"{n} tasks need {n} distinct POI nodes; only {nodes.size} candidates")
    chosen = rng.choice(nodes, size=n, replace=False)
    when = np.sort(np.floor(start_s + rng.random(n) * length_s))
    pairs = enumerate(zip(chosen.tolist(), when.tolist(), strict=True))
    return [Task(TaskId(f"{prefix}poi{i:02d}"), int(v), float(w)) for i, (v, w) in pairs]


def simulate(
    city: City,
    demand: DemandSet,
    tasks: Sequence[Task],
    config: SimConfig,
    dispatcher: Dispatcher,
    *,
    on_epoch: Callable[[int, int], None] | None = None,
    start_nodes: Sequence[int] | None = None,
    n_epochs: int | None = None,
    drift: Drift | None = None,
) -> RunTrace:
    """Run one operating horizon of ``demand`` (docs/METHOD.md section 10).

    Parameters
    ----------
    city : the city (its horizon fixes the epochs: ``horizon.length_s / epoch_s`` of them from 08:00).
    demand : the day's requests (node indices, whole seconds).
    tasks : monitoring tasks (``poi_tasks``), registered with the dispatcher before the first epoch.
    config : fleet sizes and seeds.
    dispatcher : where the decisions come from.
    on_epoch : called with (epochs done, epochs in all) after each epoch, for progress bars.
    start_nodes : the taxis' start nodes (instrumented first), instead of seeded random nodes.
    n_epochs : run only the horizon's first ``n_epochs`` epochs (a short demo); the run then ends when the
        next epoch would start, and it is the first ``n_epochs`` epochs of the whole horizon's run.
    drift : the idle drift's map (default: ``drift_map(city, config.drift_radius_m)``, kept per process).
    """
    hz = city.horizon
    start_s = hz.start_s(demand.date)
    n_epochs, end_s = _epochs(hz, start_s, n_epochs)
    last_epoch_s = start_s + (n_epochs - 1) * hz.epoch_s
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x51D]))
    taxis = _fleet(config, city.network.n_nodes, rng, start_nodes)
    by_id = {t.id: t for t in taxis}
    dm: Drift | None = None
    if config.drift:
        dm = drift if drift is not None else drift_map(city, config.drift_radius_m)

    dispatcher.add_tasks(list(tasks))
    requests = sorted(demand.requests, key=lambda r: (r.time_s, r.id))
    posted = [r for r in requests if r.time_s <= last_epoch_s]
    books = _Books()
    nxt = 0
    for e in range(n_epochs):
        now = start_s + e * hz.epoch_s
        # 1. move: jobs run on; finished jobs leave their taxi vacant at the last node
        _move(taxis, now)
        # 2. new requests
        nxt = _post(books, posted, nxt, now, config.id_prefix, dm)
        # 3. decide
        snapshot = _snapshot(f"{config.id_prefix}{demand.date}-{e:03d}", now, books, taxis, config)
        out = dispatcher.epoch(snapshot)
        # 4. apply
        _apply(city, books, by_id, out, now)
        books.epochs.append(_epoch_record(now, snapshot, out))
        # 5. idle taxis drift until the next epoch
        if dm is not None:
            _drift(dm, taxis, books.recent, now, config, hz.epoch_s, rng)
        if on_epoch is not None:
            on_epoch(e + 1, n_epochs)

    counts = {k: dispatcher.interval_counts(k) for k in hz.day_intervals(hz.interval_of(start_s))}
    return RunTrace(
        config=config,
        demand=demand.manifest(),
        start_s=start_s,
        end_s=end_s,
        epoch_s=hz.epoch_s,
        riders=tuple(books.records.values()),
        tasks=tuple(sorted(dispatcher.tasks(), key=lambda t: (t.scheduled_at_s, t.id))),
        assignments=tuple(books.assignments),
        counts=counts,
        epochs=tuple(books.epochs),
        n_unposted=len(requests) - len(posted),
    )


@dataclass(slots=True)
class _Books:
    """What a run keeps as it goes: every rider's record, the riders waiting, the Step 3 assignments (with
    their epoch's time), the epochs' records and the recent requests' (time, origin cell) for the drift
    density."""

    records: dict[RiderId, RiderRecord] = field(default_factory=dict)
    waiting: dict[RiderId, Rider] = field(default_factory=dict)
    assignments: list[tuple[float, TaskAssignment]] = field(default_factory=list)
    epochs: list[EpochRecord] = field(default_factory=list)
    recent: deque[tuple[float, int]] = field(default_factory=deque)


def _snapshot(
    epoch_id: str, now: float, books: _Books, taxis: Sequence[_TaxiState], config: SimConfig
) -> Snapshot:
    """What the platform posts at ``now``: the riders waiting and every taxi's node and state (a
    ``wait_only`` run posts its instrumented taxis as ordinary ones)."""
    return Snapshot(
        epoch_id=epoch_id,
        time_s=now,
        riders=tuple(books.waiting.values()),
        taxis=tuple(
            Taxi(t.id, t.node, t.instrumented and not config.wait_only, t.job is None) for t in taxis
        ),
    )


def _epochs(hz: Horizon, start_s: float, n_epochs: int | None) -> tuple[int, float]:
    """The number of epochs to run (the whole horizon's when None) and when the run ends."""
    if n_epochs is None:
        return hz.length_s // hz.epoch_s, start_s + hz.length_s
    if not 1 <= n_epochs <= hz.length_s // hz.epoch_s:
        raise ValueError(f"n_epochs must lie in 1..{hz.length_s // hz.epoch_s}, got {n_epochs}")
    return n_epochs, start_s + n_epochs * hz.epoch_s


def _fleet(
    config: SimConfig, n_nodes: int, rng: np.random.Generator, start_nodes: Sequence[int] | None
) -> list[_TaxiState]:
    """The taxis (instrumented first) at ``start_nodes``, else at seeded random nodes (drawn either way)."""
    pfx = config.id_prefix
    n_taxis = config.n_instrumented + config.n_ordinary
    starts = rng.integers(n_nodes, size=n_taxis)
    if start_nodes is not None:
        if len(start_nodes) != n_taxis:
            raise ValueError(f"start_nodes has {len(start_nodes)} nodes for {n_taxis} taxis")
        starts = np.asarray(start_nodes, dtype=np.int64)
    return [
        _TaxiState(TaxiId(f"{pfx}i{k:03d}"), True, int(starts[k])) for k in range(config.n_instrumented)
    ] + [
        _TaxiState(TaxiId(f"{pfx}o{k:03d}"), False, int(starts[config.n_instrumented + k]))
        for k in range(config.n_ordinary)
    ]


def _move(taxis: Sequence[_TaxiState], now: float) -> None:
    """Every taxi with a job where its job has it at ``now``; a finished job leaves its taxi vacant."""
    for t in taxis:
        if t.job is not None:
            t.node = t.job.node_at(now)
            if t.job.done_by(now):
                t.job = None


def _post(books: _Books, posted: Sequence[Request], nxt: int, now: float, pfx: str, dm: Drift | None) -> int:
    """The requests from ``posted[nxt]`` on made by ``now`` start waiting; the index of the next one."""
    while nxt < len(posted) and posted[nxt].time_s <= now:
        r = posted[nxt]
        rid = RiderId(pfx + r.id)
        books.waiting[rid] = Rider(rid, r.origin, r.destination, r.time_s)
        books.records[rid] = RiderRecord(rid, r.time_s)
        if dm is not None:
            books.recent.append((r.time_s, int(dm.node_cell[r.origin])))
        nxt += 1
    return nxt


def _apply(city: City, books: _Books, by_id: Mapping[TaxiId, _TaxiState], out: Outcome, now: float) -> None:
    """The decision's matches and assignments become the taxis' jobs; expired riders leave."""
    for m in out.rider_matches:
        rec = books.records[m.rider_id]
        rec.matched_at_s, rec.step, rec.taxi_id, rec.pickup_s = now, m.step, m.taxi_id, m.wait_s
        books.waiting.pop(m.rider_id)
        t = by_id[m.taxi_id]
        t.job, t.target, t.at_target = Job.along(city, m.path, now), -1, False
    for a in out.task_assignments:
        t = by_id[a.taxi_id]
        t.job, t.target, t.at_target = Job.along(city, a.path, now), -1, False
        books.assignments.append((now, a))
    for rid in out.expired_rider_ids:
        if rid in books.waiting:
            books.waiting.pop(rid)
            books.records[rid].left_at_s = now


def _epoch_record(now: float, snapshot: Snapshot, out: Outcome) -> EpochRecord:
    """What the epoch at ``now`` saw and decided."""
    return EpochRecord(
        time_s=now,
        waiting=len(snapshot.riders),
        vacant_instrumented=sum(1 for x in snapshot.taxis if x.vacant and x.instrumented),
        vacant_ordinary=sum(1 for x in snapshot.taxis if x.vacant and not x.instrumented),
        step1=sum(1 for m in out.rider_matches if m.step == 1),
        step2=sum(1 for m in out.rider_matches if m.step == 2),
        step3=len(out.task_assignments),
        expired=len(out.expired_rider_ids),
        solve_ms=out.solve_ms,
    )


def _drift(
    dm: Drift,
    taxis: Sequence[_TaxiState],
    recent: deque[tuple[float, int]],
    now: float,
    config: SimConfig,
    epoch_s: int,
    rng: np.random.Generator,
) -> None:
    """Move every idle vacant taxi toward its drift target for one epoch (in taxi order: seeded draws)."""
    cutoff = now - config.drift_window_s
    while recent and recent[0][0] < cutoff:
        recent.popleft()
    cells = np.fromiter((c for _, c in recent), dtype=np.int64, count=len(recent))
    n_cells = int(dm.node_cell.max()) + 1 if dm.node_cell.size else 0
    density = np.bincount(cells, minlength=n_cells).astype(np.float64)  # requests per cell: exact counts
    rethink = epoch_s / config.drift_rethink_s
    for t in taxis:
        if t.job is not None:
            continue
        if t.target < 0 or (t.at_target and rng.random() < rethink):
            t.target, t.at_target = dm.choose_target(t.node, density, rng), False
            if t.target < 0:
                continue
        if t.at_target:
            continue
        t.node, _ = dm.walk(t.target, t.node, float(epoch_s))
        if t.node == int(dm.hubs[t.target]):
            t.at_target = True
