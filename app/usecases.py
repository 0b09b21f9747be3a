"""Use cases: the only door to the store. They take the core's types (a resolved epoch, tasks, an interval
key) and return the core's results; the API turns requests into those types (``app.api.inputs``) and
renders the results (``app.schemas``). The exactly-once epoch flow is ``DispatchService.submit_epoch``."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from app.errors import (
    Busy,
    EpochConflict,
    FieldIssue,
    InvalidInput,
    NoData,
    StaleEpoch,
    TaskConflict,
    Unavailable,
    UnknownEpoch,
)
from app.ports import (
    CityState,
    DispatchStore,
    EpochCommit,
    PutTasksResult,
    RewindResult,
    StoredEpoch,
)
from services.city import City
from services.ledger import counts_view, dense_counts
from services.model import (
    CountsView,
    Decision,
    IntervalKey,
    RiderMatch,
    Snapshot,
    Task,
    TaskAssignment,
    TaxiId,
)
from services.rfc3339 import format_time
from services.sensing.sensing import coverage_rate, gamma

__all__ = [
    "CityCatalog",
    "DecideFn",
    "EpochRenderer",
    "EpochCommand",
    "EpochResult",
    "EpochOutcome",
    "StoredDecision",
    "EpochReader",
    "EpochLog",
    "EpochRoutes",
    "Coverage",
    "DispatchService",
    "EpochLimits",
    "StreamChange",
    "LOOKAHEAD_INTERVALS",
]

log = logging.getLogger(__name__)

LOOKAHEAD_INTERVALS = 2  # intervals after the epoch's own that are loaded before solving

DecideFn = Callable[[City, CountsView, Snapshot, Sequence[Task]], Decision]


class CityCatalog(Protocol):
    """The served cities (implemented by ``app.cities.CityRegistry``)."""

    def names(self) -> list[str]: ...

    def get(self, name: str) -> City:
        """The city; raises ``app.errors.UnknownCityError`` (or a subclass) when not served."""


@dataclass(frozen=True, slots=True)
class EpochCommand:
    """One posted epoch, validated and resolved to node indices at the edge (``app.api.inputs``).

    ``body_hash`` is the sha256 of the request's canonical JSON (``app.schemas.dispatch.body_hash``, computed
    by the API from the validated request model). It is stored with the commit: a later post of the same
    epoch id is a replay only if its hash is equal, so its definition never changes. ``time_text`` is the
    epoch time as posted (RFC 3339 with the client's offset), echoed in the response and the recorded demand.
    """

    snapshot: Snapshot
    body_hash: str
    time_text: str


@dataclass(frozen=True, slots=True)
class EpochResult:
    """A decided epoch, before its commit: what the response document shows (``app.schemas.dispatch``).

    ``interval`` is the epoch's own sensing interval; ``gamma_before`` and ``gamma_after`` are Gamma over
    that day's horizon intervals at the epoch's start and with its visits counted; ``attempts`` counts the
    solves (a lost commit race solves again).
    """

    city: City
    epoch: EpochCommand
    decision: Decision
    interval: IntervalKey
    solve_ms: float
    attempts: int
    gamma_before: float
    gamma_after: float


EpochRenderer = Callable[[EpochResult], str]
"""The response document of a decided epoch, committed with it and returned verbatim to replays."""


@dataclass(frozen=True, slots=True)
class EpochOutcome:
    """The response of one epoch post and what it changed (nothing when ``replayed``)."""

    response_json: str
    replayed: bool
    matches_by_step: dict[int, int] = field(default_factory=dict)
    n_task_assignments: int = 0
    attempts: int = 0


@dataclass(frozen=True, slots=True)
class StoredDecision:
    """A committed epoch's decision read back from its stored response document, in core types.

    ``trip_time_s`` of a match is NaN in a document stored before responses carried it; the riders' and
    routes' ``path`` are node indices again; ``kappa`` of an assignment is NaN (not in the document).
    """

    epoch_id: str
    time_s: float
    rider_matches: tuple[RiderMatch, ...]
    task_assignments: tuple[TaskAssignment, ...]
    tasks_completed: tuple[Task, ...]


EpochReader = Callable[[City, str], StoredDecision]
"""The decision inside a stored response document (the inverse of an ``EpochRenderer``)."""


@dataclass(frozen=True, slots=True)
class EpochLog:
    """How many epochs a city has committed, and the last one (``None`` before the first)."""

    city: City
    committed: int
    last_epoch_id: str | None
    last_epoch_time_s: float | None


@dataclass(frozen=True, slots=True)
class EpochRoutes:
    """What a committed epoch planned: its decision, and the tasks it touched as it left them (the POIs its
    routes head for, assigned to their taxi and reached at the route's end; the tasks it completed)."""

    city: City
    decision: StoredDecision
    tasks: tuple[Task, ...]


@dataclass(frozen=True, slots=True)
class StreamChange:
    """What a rewind or a reset did to a city's epoch stream (times are POSIX seconds, None when unset)."""

    city: City
    action: str
    previous_time_s: float | None
    time_s: float | None
    committed: int
    deleted: int


@dataclass(frozen=True, slots=True)
class Coverage:
    """The grid counts of one sensing interval: ``counts`` is Lambda over every cell; ``gamma_so_far`` is
    Gamma over that day's horizon intervals as counted so far."""

    city: City
    interval: IntervalKey
    counts: NDArray[np.int64]
    coverage_rate: float
    gamma_so_far: float


def _gamma_before_after(
    city: City, counts: CountsView, decision: Decision, day: Sequence[IntervalKey]
) -> tuple[float, float]:
    """Gamma over the day's horizon intervals at the epoch's start and once its visits are counted."""
    after = {k: arr.copy() for k, arr in counts.counts.items()}
    for visit in decision.visits:  # each visit is a new (taxi, interval, cell): Lambda + 1
        arr = after.get(visit.interval)
        if arr is not None:
            arr[visit.cell] += 1
    return gamma(city, counts.counts, day), gamma(city, after, day)


@dataclass(frozen=True, slots=True)
class EpochLimits:
    """How long a city's records live (``retention_s``), how often a commit that lost a race is retried,
    how many epochs are solved at once and how long one waits for a slot, and how far ahead of the clock an
    epoch may be dated."""

    retention_s: int = 8 * 86400
    commit_attempts: int = 8
    max_solves: int = 2
    solve_queue_s: float = 30.0
    max_ahead_s: float = 86400.0


class DispatchService:
    """The use cases of the API: cities, tasks, epochs and coverage over one store.

    ``render_epoch`` writes the response document of a decided epoch (the API's, ``app.schemas.dispatch``):
    it is committed with the epoch in one atomic step, so a replay is answered with the same bytes;
    ``read_epoch`` reads a stored document back into core types.
    """

    def __init__(
        self,
        cities: CityCatalog,
        store: DispatchStore,
        decide: DecideFn,
        *,
        render_epoch: EpochRenderer,
        read_epoch: EpochReader,
        limits: EpochLimits = EpochLimits(),
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.cities = cities
        self.store = store
        self.decide = decide
        self.render_epoch = render_epoch
        self.read_epoch = read_epoch
        self.retention_s = limits.retention_s
        self.commit_attempts = limits.commit_attempts
        self.solve_queue_s = limits.solve_queue_s
        self._solve_slots = threading.BoundedSemaphore(limits.max_solves)
        self.max_ahead_s = limits.max_ahead_s
        self.clock = clock
        self.warming: threading.Event | None = None
        """Set by the app's start-up: unset while the cities are being warmed up (``ready`` is 503)."""

    # ------------------------------------------------------------------ cities

    def city(self, name: str) -> City:
        """The city called ``name`` (the catalog raises ``UnknownCityError``, a 404, when not served)."""
        return self.cities.get(name)

    def city_names(self) -> list[str]:
        """Names of the served cities."""
        return sorted(self.cities.names())

    # ------------------------------------------------------------------ tasks

    def put_tasks(self, name: str, tasks: Sequence[Task]) -> PutTasksResult:
        """Register tasks, idempotent per id (409 naming the conflicting ids' positions; nothing written)."""
        self.city(name)
        result = self.store.put_tasks(name, tasks)
        if result.conflicts:
            index = {t.id: i for i, t in enumerate(tasks)}
            raise TaskConflict(
                "tasks exist with different content: " + ", ".join(map(str, result.conflicts)),
                [
                    FieldIssue(f"[{index[c]}].id", f"task {c!r} exists with different content")
                    for c in result.conflicts
                ],
            )
        return result

    def list_tasks(self, name: str) -> tuple[City, list[Task]]:
        """The city and its tasks (open ones, and finished ones within the retention), in scheduled order."""
        city = self.city(name)
        return city, sorted(self.store.list_tasks(name), key=lambda t: (t.scheduled_at_s, t.id))

    # ------------------------------------------------------------------ epochs

    def _replay(self, stored: StoredEpoch, digest: str) -> EpochOutcome:
        if stored.body_hash != digest:
            raise EpochConflict(
                f"epoch {stored.epoch_id!r} was committed with a different body",
                [FieldIssue("epoch_id", "already used with a different body")],
            )
        return EpochOutcome(response_json=stored.response_json, replayed=True)

    def _load(
        self, name: str, intervals: set[IntervalKey], taxi_ids: Sequence[TaxiId], time_s: float, k0: int
    ) -> CityState:
        # the taxis' counted pairs from the epoch's interval on: the paths it plans start now
        state = self.store.load_state(name, sorted(intervals), taxi_ids, visits_from=IntervalKey(k0))
        if state.last_epoch_time_s is not None and time_s < state.last_epoch_time_s:
            raise StaleEpoch(
                f"epoch time is older than the last committed epoch {state.last_epoch_id!r}",
                [FieldIssue("time", "older than the last committed epoch")],
            )
        return state

    def _expire(self, tasks: Sequence[Task], time_s: float) -> tuple[list[Task], list[Task]]:
        """The open tasks an epoch at ``time_s`` considers, and those it expires: still pending although
        scheduled longer ago than the retention (they leave the open set as ``expired``)."""
        cutoff = time_s - self.retention_s
        keep: list[Task] = []
        expired: list[Task] = []
        for t in tasks:
            if t.status == "pending" and t.scheduled_at_s < cutoff:
                expired.append(dataclasses.replace(t, status="expired"))
            else:
                keep.append(t)
        return keep, expired

    def _check_window(self, city: City, time_s: float) -> None:
        """422 on ``time`` when the epoch lies more than ``max_ahead_s`` after the service clock: one typo
        (year 2962) would otherwise make every later, correct epoch of the city stale. Older epochs are
        fine (replays of history)."""
        now_s = self.clock()
        if time_s > now_s + self.max_ahead_s:
            latest = format_time(now_s + self.max_ahead_s, city.horizon.timezone)
            raise InvalidInput.at(
                "time",
                f"more than {self.max_ahead_s:.0f} s after the service clock: at most {latest} "
                "(SD_EPOCH_MAX_AHEAD_S)",
            )

    def submit_epoch(self, name: str, epoch: EpochCommand) -> EpochOutcome:
        """Solve and commit one epoch exactly once (docs/DESIGN.md, "Exactly-once epochs"). At most
        ``max_solves`` epochs are solved at once: one finding every slot taken waits ``solve_queue_s``, then
        is refused (``Busy``, a 503) having read and written nothing; a replay needs no slot."""
        city = self.city(name)
        snapshot = epoch.snapshot
        self._check_window(city, snapshot.time_s)
        stored = self.store.get_epoch(name, snapshot.epoch_id)
        if stored is not None:
            return self._replay(stored, epoch.body_hash)

        if not self._solve_slots.acquire(timeout=self.solve_queue_s):
            raise Busy(
                f"every solve slot is taken (waited {self.solve_queue_s:g} s for one): too many epochs at "
                "once; retry later"
            )
        try:
            return self._solve_and_commit(name, city, epoch)
        finally:
            self._solve_slots.release()

    def _solve_and_commit(self, name: str, city: City, epoch: EpochCommand) -> EpochOutcome:
        """``submit_epoch`` within a solve slot: solve against the loaded state, commit, and on a version
        conflict load and solve again."""
        snapshot = epoch.snapshot
        k0 = city.horizon.interval_of(snapshot.time_s)
        day = city.horizon.day_intervals(k0)
        # the epoch's interval and the next two (paths run on), plus the day's horizon for Gamma
        intervals = {IntervalKey(k0 + i) for i in range(LOOKAHEAD_INTERVALS + 1)} | set(day)
        instrumented = [t.id for t in snapshot.taxis if t.instrumented]
        for attempt in range(1, self.commit_attempts + 1):
            state = self._load(name, intervals, instrumented, snapshot.time_s, k0)
            started = time.perf_counter()
            while True:
                counts = counts_view(state.counts, state.visited, city.grid.n_cells, sorted(intervals))
                tasks, expired = self._expire(state.tasks, snapshot.time_s)
                decision = self.decide(city, counts, snapshot, tasks)
                missing = set(decision.intervals_touched) - intervals
                if not missing:
                    break
                intervals |= missing  # the solve reached intervals it read as zero: load them, solve again
                state = self._load(name, intervals, instrumented, snapshot.time_s, k0)
            solve_ms = (time.perf_counter() - started) * 1000.0
            before, after = _gamma_before_after(city, counts, decision, day)
            result = EpochResult(city, epoch, decision, k0, solve_ms, attempt, before, after)
            response = self.render_epoch(result)
            commit = self.store.commit_epoch(
                name,
                EpochCommit(
                    epoch_id=snapshot.epoch_id,
                    body_hash=epoch.body_hash,
                    time_s=snapshot.time_s,
                    expected_version=state.version,
                    visits=decision.visits,
                    task_updates=(*decision.task_updates, *expired),
                    response_json=response,
                    retention_s=self.retention_s,
                    demand_json=_demand_json(city, epoch),
                    nonce=uuid.uuid4().hex,  # per attempt: a resent commit finds it, knows it was its own
                ),
            )
            if commit.status == "committed":
                steps = {1: 0, 2: 0}
                for m in decision.rider_matches:
                    steps[m.step] += 1
                return EpochOutcome(response, False, steps, len(decision.task_assignments), attempt)
            if commit.status == "duplicate":
                if commit.stored is None:
                    raise RuntimeError("store reported a duplicate epoch without its record")
                return self._replay(commit.stored, epoch.body_hash)
            if commit.status == "stale":
                raise StaleEpoch(
                    "epoch time is older than the last committed epoch",
                    [FieldIssue("time", "older than the last committed epoch")],
                )
            log.info(
                "epoch %s of %s: version mismatch on attempt %d, solving again",
                snapshot.epoch_id,
                name,
                attempt,
            )
        raise Busy(
            f"city {name!r} is busy: {self.commit_attempts} commit attempts lost to concurrent epochs; retry"
        )

    # ------------------------------------------------------------------ admin: rewind and reset

    def rewind(self, name: str, time_s: float) -> StreamChange:
        """Set the city's last epoch time back to ``time_s`` (404 ``no_data`` with no epoch committed; 422
        on ``to`` when it is later than the last epoch time)."""
        city = self.city(name)
        result: RewindResult = self.store.rewind_epochs(name, time_s)
        if result.status == "empty":
            raise NoData(f"no epoch committed for {name!r}: nothing to rewind")
        if result.status == "ahead":
            assert result.previous_time_s is not None
            last = format_time(result.previous_time_s, city.horizon.timezone)
            raise InvalidInput.at("to", f"later than the last epoch time {last}: nothing to rewind")
        log.warning("epoch stream of %s rewound from %s to %s", name, result.previous_time_s, time_s)
        return StreamChange(city, "rewind", result.previous_time_s, time_s, result.version, 0)

    def reset(self, name: str) -> StreamChange:
        """Delete the city's epoch stream and tasks (fleet records stay)."""
        city = self.city(name)
        before = self.store.load_state(name, [], [])
        deleted = self.store.reset_epochs(name)
        log.warning("epoch stream of %s reset: %d entries deleted", name, deleted)
        return StreamChange(city, "reset", before.last_epoch_time_s, None, 0, deleted)

    # ------------------------------------------------------------------ readiness

    def ready(self) -> list[str]:
        """The served cities once the store answers, the start-up warm-up (``warming``) has finished and every
        city loads (``Unavailable``, a 503, else)."""
        if self.warming is not None and not self.warming.is_set():
            raise Unavailable(
                "warming up: the cities are loading and the routing kernels compiling (minutes on a fresh "
                "install, under a second once they are cached); epochs posted now wait for it"
            )
        self.store.ping()
        names = self.city_names()
        if not names:
            raise Unavailable("no cities are installed")
        for name in names:
            try:
                self.city(name)
            except Exception as exc:  # a broken city bundle makes the instance not ready, not crashed
                raise Unavailable(f"city {name!r} failed to load: {exc}") from exc
        return names

    # ------------------------------------------------------------------ committed epochs

    def epoch_log(self, name: str) -> EpochLog:
        """How many epochs the city has committed and which was the last."""
        city = self.city(name)
        state = self.store.load_state(name, [], [])
        return EpochLog(city, state.version, state.last_epoch_id, state.last_epoch_time_s)

    def stored_epoch(self, name: str, epoch_id: str) -> StoredEpoch:
        """The stored record of a committed epoch (404 ``unknown_epoch`` when there is none)."""
        self.city(name)
        stored = self.store.get_epoch(name, epoch_id)
        if stored is None:
            raise UnknownEpoch(
                f"no committed epoch {epoch_id!r} in {name!r} (never posted, or older than the retention)"
            )
        return stored

    def epoch_routes(self, name: str, epoch_id: str) -> EpochRoutes:
        """The paths a committed epoch planned and the tasks it touched, as it left them."""
        city = self.city(name)
        decision = self.read_epoch(city, self.stored_epoch(name, epoch_id).response_json)
        known = {t.id: t for t in self.store.list_tasks(name)}
        tasks: list[Task] = []
        for a in decision.task_assignments:
            # tasks never expire, so the task is there; were it not, its POI is the route's end and its
            # scheduled time unknown (NaN, written as null) rather than dropped
            task = known.get(a.task_id) or Task(a.task_id, a.path[-1], math.nan)
            tasks.append(
                dataclasses.replace(
                    task,
                    status="assigned",
                    completed_at_s=decision.time_s + a.travel_time_s,
                    taxi_id=a.taxi_id,
                    mode="active",
                )
            )
        tasks.extend(decision.tasks_completed)
        return EpochRoutes(city, decision, tuple(tasks))

    # ------------------------------------------------------------------ coverage

    def coverage(self, name: str, interval: IntervalKey | None) -> Coverage:
        """Lambda per cell, coverage rate and Gamma so far for one interval (default: the last epoch's)."""
        city = self.city(name)
        if interval is not None:
            k = interval
        else:
            state = self.store.load_state(name, [], [])
            if state.last_epoch_time_s is None:
                raise NoData(f"no epoch committed for {name!r} yet; pass ?interval=")
            k = city.horizon.interval_of(state.last_epoch_time_s)
        day = city.horizon.day_intervals(k)
        wanted = sorted(set(day) | {k})
        counts = {j: dense_counts(self.store.interval_counts(name, j), city.grid.n_cells) for j in wanted}
        return Coverage(city, k, counts[k], coverage_rate(city, counts[k]), gamma(city, counts, day))


def _demand_json(city: City, epoch: EpochCommand) -> str:
    """The epoch's riders for the fleet-sizing worker (a waiting rider recurs: dedupe by id)."""
    ids = city.network.node_ids
    snapshot = epoch.snapshot
    doc: dict[str, Any] = {
        "epoch_id": snapshot.epoch_id,
        "time": epoch.time_text,
        "time_s": snapshot.time_s,
        "riders": [
            {
                "id": str(r.id),
                "origin": int(ids[r.origin]),
                "destination": int(ids[r.destination]),
                "requested_at": format_time(r.requested_at_s, city.horizon.timezone),
                "requested_at_s": r.requested_at_s,
            }
            for r in snapshot.riders
        ],
    }
    return json.dumps(doc, separators=(",", ":"))
