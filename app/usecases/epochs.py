"""The epoch use cases: solve and commit a posted epoch exactly once (``EpochService.submit_epoch``), and
read committed epochs back (the log, the stored document, the routes an epoch planned). They take the core's
types (a resolved epoch) and return the core's results; the API turns requests into those types
(``app.api.inputs``) and renders the results (``app.schemas``). A committed epoch's document is its record
(``app.usecases.epoch_record``), written once and answered verbatim to its post and every replay."""

from __future__ import annotations

import dataclasses
import datetime as dt
import functools
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from typing import Any
from zoneinfo import ZoneInfo

import orjson

from app.errors import (
    Busy,
    EpochConflict,
    FieldIssue,
    InvalidInput,
    StaleEpoch,
    UnknownEpoch,
)
from app.ports import (
    CityState,
    DispatchStore,
    EpochCommit,
    StoredEpoch,
    local_day,
)
from app.usecases.cities import CityCatalog
from app.usecases.epoch_record import (
    EpochCommand,
    EpochReader,
    EpochRenderer,
    EpochResult,
    StoredDecision,
    external_ids,
    read_epoch,
    render_epoch,
)
from services.city import City
from services.epoch import until_fits
from services.ledger import counts_view
from services.model import (
    CountsView,
    Decision,
    IntervalKey,
    Snapshot,
    Task,
    TaxiId,
)
from services.rfc3339 import format_time
from services.sensing.sensing import gamma

__all__ = [
    "DecideFn",
    "EpochRenderer",
    "EpochCommand",
    "EpochResult",
    "EpochOutcome",
    "StoredDecision",
    "EpochReader",
    "EpochLog",
    "EpochRoutes",
    "EpochService",
    "EpochLimits",
    "LOOKAHEAD_INTERVALS",
    "opens_horizon",
]

log = logging.getLogger(__name__)

LOOKAHEAD_INTERVALS = 2  # intervals after the epoch's own that are loaded before solving

DecideFn = Callable[[City, CountsView, Snapshot, Sequence[Task]], Decision]


@dataclass(frozen=True, slots=True)
class EpochOutcome:
    """The response of one epoch post and what it changed (nothing when ``replayed``)."""

    response_json: str
    replayed: bool
    matches_by_step: dict[int, int] = field(default_factory=dict)
    n_task_assignments: int = 0
    attempts: int = 0


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


_Loaded = tuple[set[IntervalKey], CityState]
"""The intervals an epoch's solve reads and the city's state loaded for them."""


@dataclass(frozen=True, slots=True)
class _Solved:
    """An epoch's solve: the counts it read, the tasks it expired and its decision."""

    counts: CountsView
    expired: list[Task]
    decision: Decision


class EpochService:
    """Posted epochs solved and committed exactly once, and committed epochs read back.

    ``render_epoch`` writes the record of a decided epoch (``app.usecases.epoch_record``): it is committed
    with the epoch in one atomic step, so a replay is answered with the same bytes; ``read_epoch`` reads a
    stored record back into core types (a test may give stand-ins for both).
    """

    def __init__(
        self,
        cities: CityCatalog,
        store: DispatchStore,
        decide: DecideFn,
        *,
        render_epoch: EpochRenderer = render_epoch,
        read_epoch: EpochReader = read_epoch,
        limits: EpochLimits = EpochLimits(),
        clock: Callable[[], float] = time.time,
        foreground: Callable[[], AbstractContextManager[None]] = nullcontext,
    ) -> None:
        """``foreground``: what an epoch's request holds from its headers to its response (the embedded fleet
        worker's runs stay stopped meanwhile); the API enters it for the whole exchange
        (``app.api.foreground``)."""
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
        self.foreground = foreground

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

    def submit_epoch(self, city: City, epoch: EpochCommand) -> EpochOutcome:
        """Solve and commit one epoch of ``city`` exactly once (docs/DESIGN.md, "Exactly-once epochs"). At
        most ``max_solves`` epochs are solved at once: one finding every slot taken waits ``solve_queue_s``,
        then is refused (``Busy``, a 503) having read and written nothing; a replay needs no slot. ``city``
        is the served city the caller resolved the epoch's node indices against (``CityCatalog.get``): it
        is not looked up again."""
        name = city.name
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

    def _solver(
        self, name: str, city: City, snapshot: Snapshot, k0: int, instrumented: list[TaxiId]
    ) -> Callable[[_Loaded], tuple[_Solved, _Loaded | None]]:
        """One solve of ``snapshot`` (interval ``k0``) against the intervals loaded so far, asking for the
        intervals it reached and read as zero (loaded with the rest: the solve runs again on them), none when
        it reached none."""

        def solve(loaded: _Loaded) -> tuple[_Solved, _Loaded | None]:
            intervals, state = loaded
            counts = counts_view(state.counts, state.visited, city.grid.n_cells, sorted(intervals))
            tasks, expired = self._expire(state.tasks, snapshot.time_s)
            decision = self.decide(city, counts, snapshot, tasks)
            missing = set(decision.intervals_touched) - intervals
            if not missing:
                return _Solved(counts, expired, decision), None
            more = intervals | missing
            return _Solved(counts, expired, decision), (
                more,
                self._load(name, more, instrumented, snapshot.time_s, k0),
            )

        return solve

    def _solve_and_commit(self, name: str, city: City, epoch: EpochCommand) -> EpochOutcome:
        """``submit_epoch`` within a solve slot: solve against the loaded state, commit, and on a version
        conflict load and solve again."""
        snapshot = epoch.snapshot
        k0 = city.horizon.interval_of(snapshot.time_s)
        day = city.horizon.day_intervals(k0)
        # the epoch's interval and the next two (paths run on), plus the day's horizon for Gamma
        intervals = {IntervalKey(k0 + i) for i in range(LOOKAHEAD_INTERVALS + 1)} | set(day)
        instrumented = [t.id for t in snapshot.taxis if t.instrumented]
        demand = _DemandRecord(city, epoch)  # the riders and the fleet as posted: the same every attempt
        for attempt in range(1, self.commit_attempts + 1):
            loaded = self._load(name, intervals, instrumented, snapshot.time_s, k0)
            started = time.perf_counter()
            solved, (intervals, state) = until_fits(
                self._solver(name, city, snapshot, k0, instrumented), (intervals, loaded)
            )
            counts, expired, decision = solved.counts, solved.expired, solved.decision
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
                    demand_json=demand.json(opens_horizon(city, state.last_epoch_time_s, snapshot.time_s)),
                    demand_day=demand.day,
                    nonce=uuid.uuid4().hex,  # per attempt: a resent commit finds it, knows it was its own
                ),
            )
            if commit.status == "committed":
                by_step = decision.matches_by_step
                return EpochOutcome(response, False, by_step, len(decision.task_assignments), attempt)
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

    def epoch_log(self, name: str) -> EpochLog:
        """How many epochs the city has committed and which was the last."""
        city = self.cities.get(name)
        state = self.store.load_state(name, [], [])
        return EpochLog(city, state.version, state.last_epoch_id, state.last_epoch_time_s)

    def stored_epoch(self, name: str, epoch_id: str) -> StoredEpoch:
        """The stored record of a committed epoch (404 ``unknown_city``; ``unknown_epoch`` when there is
        none)."""
        self.cities.get(name)
        return self._stored(name, epoch_id)

    def _stored(self, name: str, epoch_id: str) -> StoredEpoch:
        """``stored_epoch`` of a city already resolved."""
        stored = self.store.get_epoch(name, epoch_id)
        if stored is None:
            raise UnknownEpoch(
                f"no committed epoch {epoch_id!r} in {name!r} (never posted, or older than the retention)"
            )
        return stored

    def epoch_routes(self, name: str, epoch_id: str) -> EpochRoutes:
        """The paths a committed epoch planned and the tasks it touched, as it left them."""
        city = self.cities.get(name)
        decision = self.read_epoch(city, self._stored(name, epoch_id).response_json)
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


def opens_horizon(city: City, last_epoch_s: float | None, time_s: float) -> bool:
    """Whether an epoch at ``time_s`` is the first the city commits within its local day's horizon (the
    last committed epoch, if any, lies before that horizon's start)."""
    hz = city.horizon
    start = hz.start_s(dt.datetime.fromtimestamp(time_s, tz=ZoneInfo(hz.timezone)).date())
    return start <= time_s < start + hz.length_s and (last_epoch_s is None or last_epoch_s < start)


@functools.lru_cache(maxsize=8192)
def _local_time(time_s: float, tz: str) -> str:
    """``format_time``, remembered: a rider still waiting is recorded again, with the same request time, by
    every epoch that posts it."""
    return format_time(time_s, tz)


class _DemandRecord:
    """What an epoch records for the fleet-sizing worker (docs/FLEET.md, "The platform's history"): its
    riders (a waiting rider recurs: the worker dedupes by id), how many instrumented and ordinary taxis it
    posted, and, for the epoch that opens the day's horizon, where each of them stood."""

    def __init__(self, city: City, epoch: EpochCommand) -> None:
        ids = external_ids(city)
        snapshot = epoch.snapshot
        tz = city.horizon.timezone
        self.city = city
        self.snapshot = snapshot
        self.day = local_day(snapshot.time_s, tz)
        instrumented = sum(1 for t in snapshot.taxis if t.instrumented)
        self._doc: dict[str, Any] = {
            "epoch_id": snapshot.epoch_id,
            "time": epoch.time_text,
            "time_s": snapshot.time_s,
            "riders": [
                {
                    "id": str(r.id),
                    "origin": ids[r.origin],
                    "destination": ids[r.destination],
                    "requested_at": _local_time(r.requested_at_s, tz),
                    "requested_at_s": r.requested_at_s,
                }
                for r in snapshot.riders
            ],
            "fleet": {"instrumented": instrumented, "ordinary": len(snapshot.taxis) - instrumented},
        }
        self._text: dict[bool, str] = {}

    def json(self, opening: bool) -> str:
        """The record, with the fleet's positions when the epoch opens the day's horizon."""
        if opening not in self._text:
            doc = self._doc
            if opening:
                ids = external_ids(self.city)
                taxis = self.snapshot.taxis
                doc = {
                    **doc,
                    "fleet_at_open": {
                        "instrumented": [ids[t.node] for t in taxis if t.instrumented],
                        "ordinary": [ids[t.node] for t in taxis if not t.instrumented],
                    },
                }
            self._text[opening] = orjson.dumps(doc).decode()
        return self._text[opening]
