"""In-process ``Store``: one lock, the embedded default; mirrors the Redis key layout and expiry."""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from itertools import repeat
from typing import Literal

from app.adapters.codec import check_fleet_record, classify_tasks, new_lock_token
from app.ports import (
    CityState,
    CommitResult,
    EnqueueResult,
    EpochCommit,
    FleetRecord,
    PublishResult,
    PutTasksResult,
    RewindResult,
    SolveRequest,
    StoredEpoch,
    WorkerBeat,
)
from services.ledger import Ledger, apply_decision
from services.model import DONE, IntervalKey, Task, TaskId, TaxiId

__all__ = ["MemoryStore"]

_Kind = Literal["count", "visit", "epoch", "demand", "meta"]
_ExpiryKey = tuple[str, _Kind, str]  # (city, kind, key within the city)


@dataclass(slots=True)
class _City:
    version: int = 0
    last_epoch_id: str | None = None
    last_time_s: float | None = None
    epochs: dict[str, StoredEpoch] = field(default_factory=dict)
    ledger: Ledger = field(default_factory=Ledger)  # counts, visits and tasks (services.ledger)
    demand: dict[str, list[str]] = field(default_factory=dict)
    fleet_current: FleetRecord | None = None
    fleet_history: list[FleetRecord] = field(default_factory=list)  # newest first
    locks: dict[str, tuple[str, float]] = field(default_factory=dict)  # name -> (token, expires at)
    solve_queue: list[SolveRequest] = field(default_factory=list)
    workers: dict[str, tuple[WorkerBeat, float]] = field(default_factory=dict)  # id -> (beat, expires at)
    # epoch time a task finished at, in the order of those times (commits come in time order: _record_done)
    done_at: dict[TaskId, float] = field(default_factory=dict)
    # (interval, taxi) -> (its visited cells' set in the ledger, that set's size, the (interval, cell) pairs):
    # the pairs load_state hands out, built again only when the set grew or was replaced (sets only grow)
    visit_pairs: dict[
        tuple[IntervalKey, TaxiId], tuple[set[int], int, frozenset[tuple[IntervalKey, int]]]
    ] = field(default_factory=dict, compare=False, repr=False)  # derived from ledger.visits: not state


def _record_done(c: _City, task_id: TaskId, at_s: float) -> None:
    """Note that ``task_id`` finished at ``at_s``, at the end of ``done_at`` so that it stays in time order
    (an epoch is committed only at or after the last one's time)."""
    c.done_at.pop(task_id, None)
    c.done_at[task_id] = at_s


def _prune_done(c: _City, before_s: float) -> None:
    """Drop the finished tasks that finished before ``before_s`` (epoch time), as the Redis store does:
    the oldest first, stopping at the first that stays (``done_at`` is in time order)."""
    while c.done_at:
        task_id, at = next(iter(c.done_at.items()))
        if at >= before_s:
            return
        del c.done_at[task_id]
        c.ledger.done.pop(task_id, None)


def _visit_key(interval: IntervalKey, taxi: TaxiId) -> str:
    return f"{int(interval)}:{taxi}"


class MemoryStore:
    """Thread-safe in-memory store; counts, visits, epoch records and demand expire after ``retention_s``."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        """Create an empty store; ``clock`` (seconds) drives expiry."""
        self._lock = threading.Lock()
        self._clock = clock
        self._cities: dict[str, _City] = {}
        self._expires_at: dict[_ExpiryKey, float] = {}
        self._heap: list[tuple[float, _ExpiryKey]] = []

    # -- expiry (lazy, like Redis: expired entries are invisible and dropped on the next access) --------

    def _touch(self, key: _ExpiryKey, ttl_s: int) -> None:
        self._touch_all((key,), ttl_s)

    def _touch_all(self, keys: Iterable[_ExpiryKey], ttl_s: int) -> None:
        """Let each of ``keys`` (distinct) live ``ttl_s`` from now."""
        at = self._clock() + ttl_s
        expires_at, heap = self._expires_at, self._heap
        for key in keys:
            expires_at[key] = at
            heapq.heappush(heap, (at, key))

    def _purge(self) -> None:
        now = self._clock()
        while self._heap and self._heap[0][0] <= now:
            at, key = heapq.heappop(self._heap)
            if self._expires_at.get(key) != at:
                continue  # refreshed since this entry was pushed
            del self._expires_at[key]
            self._drop(key)

    def _drop(self, key: _ExpiryKey) -> None:
        city_name, kind, name = key
        city = self._cities.get(city_name)
        if city is None:
            return
        if kind == "count":
            city.ledger.counts.pop(IntervalKey(int(name)), None)
        elif kind == "visit":
            k, taxi = name.split(":", 1)
            city.ledger.visits.pop((IntervalKey(int(k)), TaxiId(taxi)), None)
            city.visit_pairs.pop((IntervalKey(int(k)), TaxiId(taxi)), None)
        elif kind == "epoch":
            city.epochs.pop(name, None)
        elif kind == "meta":
            city.version, city.last_epoch_id, city.last_time_s = 0, None, None
        else:
            city.demand.pop(name, None)

    def _city(self, city: str, *, create: bool = False) -> _City:
        self._purge()
        state = self._cities.get(city)
        if state is None:
            state = _City()
            if create:  # reads of an unknown city do not leave an entry behind
                self._cities[city] = state
        return state

    # -- the port ------------------------------------------------------------------------------------

    def ping(self) -> None:
        """Always reachable."""

    def get_epoch(self, city: str, epoch_id: str) -> StoredEpoch | None:
        """The stored record of an epoch, if any."""
        with self._lock:
            return self._city(city).epochs.get(epoch_id)

    def load_state(
        self,
        city: str,
        intervals: Sequence[IntervalKey],
        taxi_ids: Sequence[TaxiId],
        *,
        visits_from: IntervalKey | None = None,
    ) -> CityState:
        """A copy of the city's state for the given intervals and taxis."""
        with self._lock:
            c = self._city(city)
            ks = list(dict.fromkeys(intervals))
            vks = ks if visits_from is None else [k for k in ks if k >= visits_from]
            visited = {taxi: self._visited(c, taxi, vks) for taxi in dict.fromkeys(taxi_ids)}
            return CityState(
                version=c.version,
                last_epoch_id=c.last_epoch_id,
                last_epoch_time_s=c.last_time_s,
                counts={k: dict(c.ledger.counts.get(k, {})) for k in ks},
                visited=visited,
                tasks=[c.ledger.tasks[t] for t in sorted(c.ledger.tasks)],
            )

    @staticmethod
    def _visited(c: _City, taxi: TaxiId, ks: Sequence[IntervalKey]) -> frozenset[tuple[IntervalKey, int]]:
        """The (interval, cell) pairs ``taxi`` is counted in over ``ks``: the one frozen set an interval's
        pairs are kept as when only one of ``ks`` has any (the common case: no copy), their union else."""
        visits, cache = c.ledger.visits, c.visit_pairs
        found: list[frozenset[tuple[IntervalKey, int]]] = []
        for k in ks:
            cells = visits.get((k, taxi))
            if cells:
                hit = cache.get((k, taxi))
                if hit is None or hit[0] is not cells or hit[1] != len(cells):
                    hit = cache[(k, taxi)] = (cells, len(cells), frozenset(zip(repeat(k), cells)))
                found.append(hit[2])
        if len(found) == 1:
            return found[0]
        return frozenset().union(*found)

    def commit_epoch(self, city: str, commit: EpochCommit) -> CommitResult:
        """Check and apply one epoch under the lock (see ``app.ports.Store.commit_epoch``)."""
        with self._lock:
            c = self._city(city, create=True)
            stored = c.epochs.get(commit.epoch_id)
            if stored is not None:
                if commit.nonce and stored.nonce == commit.nonce:  # this very commit, sent again
                    return CommitResult("committed", new_version=c.version)
                return CommitResult("duplicate", stored=stored)
            if commit.expected_version != c.version:
                return CommitResult("version_mismatch")
            if c.last_time_s is not None and commit.time_s < c.last_time_s:
                return CommitResult("stale")
            ttl = int(commit.retention_s)
            apply_decision(c.ledger, commit.visits, commit.task_updates)
            for t in commit.task_updates:
                if t.status in DONE:
                    _record_done(c, t.id, float(commit.time_s))
            _prune_done(c, float(commit.time_s) - ttl)
            # like Redis: every key a visit names lives on from this commit (each key touched once)
            keys = dict.fromkeys((IntervalKey(int(v.interval)), v.taxi_id) for v in commit.visits)
            touched: dict[_ExpiryKey, None] = {}
            for k, taxi in keys:
                touched[(city, "count", str(int(k)))] = None
                touched[(city, "visit", _visit_key(k, taxi))] = None
            self._touch_all(touched, ttl)
            c.epochs[commit.epoch_id] = StoredEpoch(
                commit.epoch_id, commit.body_hash, float(commit.time_s), commit.response_json, commit.nonce
            )
            self._touch((city, "epoch", commit.epoch_id), ttl)
            if commit.demand_json is not None:
                day = commit.demand_day
                c.demand.setdefault(day, []).append(commit.demand_json)
                self._touch((city, "demand", day), ttl)
            c.version += 1
            c.last_epoch_id = commit.epoch_id
            c.last_time_s = float(commit.time_s)
            self._touch((city, "meta", ""), ttl)
            return CommitResult("committed", new_version=c.version)

    def rewind_epochs(self, city: str, time_s: float) -> RewindResult:
        """Set the last epoch time back to ``time_s`` (see ``app.ports.Store.rewind_epochs``)."""
        with self._lock:
            c = self._city(city)
            last = c.last_time_s
            if last is None:
                return RewindResult("empty", None, c.version)
            if time_s > last:
                return RewindResult("ahead", last, c.version)
            c.last_time_s = float(time_s)
            return RewindResult("rewound", last, c.version)

    def reset_epochs(self, city: str) -> int:
        """Forget the city's epoch stream and tasks; its fleet records, requests and locks stay."""
        with self._lock:
            old = self._cities.get(city)
            if old is None:
                return 0
            deleted = (
                int(old.version > 0)
                + len(old.epochs)
                + len(old.ledger.counts)
                + len(old.ledger.visits)
                + len(old.demand)
                + len(old.ledger.tasks)
                + len(old.ledger.done)
            )
            self._cities[city] = _City(
                fleet_current=old.fleet_current,
                fleet_history=old.fleet_history,
                locks=old.locks,
                solve_queue=old.solve_queue,
                workers=old.workers,
            )
            for key in [k for k in self._expires_at if k[0] == city]:
                del self._expires_at[key]  # their heap entries no longer match: skipped when popped
            return deleted

    def put_tasks(self, city: str, tasks: Sequence[Task]) -> PutTasksResult:
        """Register tasks, idempotent per id (finished ones included); on any conflict nothing is written."""
        with self._lock:
            c = self._city(city, create=True)
            outcome = classify_tasks(c.ledger.task, tasks)
            c.ledger.tasks.update(outcome.to_write)
            return outcome.result

    def list_tasks(self, city: str) -> list[Task]:
        """The city's open tasks and its finished ones still within the retention, by id."""
        with self._lock:
            c = self._city(city)
            both = {**c.ledger.done, **c.ledger.tasks}
            return [both[t] for t in sorted(both)]

    def interval_counts(self, city: str, interval: IntervalKey) -> dict[int, int]:
        """Lambda by cell for one interval (cells with zero count absent)."""
        with self._lock:
            return dict(self._city(city).ledger.counts.get(interval, {}))

    def list_intervals(self, city: str) -> list[IntervalKey]:
        """Intervals with at least one count, ascending."""
        with self._lock:
            return sorted(k for k, counts in self._city(city).ledger.counts.items() if counts)

    def recorded_demand(self, city: str, day: str) -> list[str]:
        """Demand recorded on one local day (``YYYYMMDD``), in commit order."""
        with self._lock:
            return list(self._city(city).demand.get(day, []))

    def recorded_epochs(self, city: str, days: Sequence[str]) -> list[int]:
        """The number of records of each day."""
        with self._lock:
            demand = self._city(city).demand
            return [len(demand.get(day, ())) for day in days]

    # -- fleet sizing -----------------------------------------------------------------------------------

    def publish_recommendation(self, city: str, record: FleetRecord, history_limit: int) -> PublishResult:
        """Compare-and-set the current recommendation (version + 1) and push it on the bounded history."""
        check_fleet_record(record, "published", history_limit)
        assert record.version is not None
        with self._lock:
            c = self._city(city, create=True)
            current = (
                0 if c.fleet_current is None or c.fleet_current.version is None else c.fleet_current.version
            )
            if record.version != current + 1:
                return PublishResult("version_mismatch", current)
            c.fleet_current = record
            c.fleet_history.insert(0, record)
            del c.fleet_history[history_limit:]
            return PublishResult("published", record.version)

    def record_solve_failure(self, city: str, record: FleetRecord, history_limit: int) -> None:
        """Push a failed record on the bounded history."""
        check_fleet_record(record, "failed", history_limit)
        with self._lock:
            c = self._city(city, create=True)
            c.fleet_history.insert(0, record)
            del c.fleet_history[history_limit:]

    def current_recommendation(self, city: str) -> FleetRecord | None:
        """The last published recommendation, if any."""
        with self._lock:
            return self._city(city).fleet_current

    def recommendation_history(self, city: str, limit: int) -> list[FleetRecord]:
        """Up to ``limit`` history entries, newest first."""
        with self._lock:
            return list(self._city(city).fleet_history[: max(limit, 0)])

    def acquire_lock(self, city: str, name: str, ttl_s: float) -> str | None:
        """Take the lock unless a holder's TTL (on this store's clock) has not run out."""
        if not ttl_s > 0:
            raise ValueError(f"ttl_s must be positive, got {ttl_s}")
        with self._lock:
            c = self._city(city, create=True)
            now = self._clock()
            held = c.locks.get(name)
            if held is not None and held[1] > now:
                return None
            token = new_lock_token()
            c.locks[name] = (token, now + ttl_s)
            return token

    def release_lock(self, city: str, name: str, token: str) -> bool:
        """Release the lock if ``token`` holds it and it has not expired."""
        with self._lock:
            c = self._city(city)
            held = c.locks.get(name)
            if held is None or held[0] != token or held[1] <= self._clock():
                return False
            del c.locks[name]
            return True

    def enqueue_solve_request(self, city: str, request: SolveRequest) -> EnqueueResult:
        """Queue the request unless one is pending."""
        with self._lock:
            c = self._city(city, create=True)
            if c.solve_queue:
                return EnqueueResult(c.solve_queue[0], False)
            c.solve_queue.append(request)
            return EnqueueResult(request, True)

    def claim_solve_request(self, city: str) -> SolveRequest | None:
        """Pop the pending request, if any."""
        with self._lock:
            c = self._city(city)
            return c.solve_queue.pop(0) if c.solve_queue else None

    def pending_solve_request(self, city: str) -> SolveRequest | None:
        """The pending request, if any (left queued)."""
        with self._lock:
            c = self._city(city)
            return c.solve_queue[0] if c.solve_queue else None

    def record_worker_beat(self, city: str, beat: WorkerBeat, keep_s: float) -> None:
        """Keep ``beat`` as its worker's latest; every kept beat lives ``keep_s`` on this store's clock from
        now (as the Redis key does) and beats seen ``keep_s`` before this one are dropped."""
        if not keep_s > 0:
            raise ValueError(f"keep_s must be positive, got {keep_s}")
        with self._lock:
            c = self._city(city, create=True)
            until = self._clock() + keep_s
            cutoff = beat.seen_at_s - keep_s
            c.workers = {w: (b, until) for w, (b, _) in c.workers.items() if b.seen_at_s >= cutoff}
            c.workers[beat.worker_id] = (beat, until)

    def worker_beats(self, city: str) -> list[WorkerBeat]:
        """The kept beats, newest first."""
        with self._lock:
            c = self._city(city)
            now = self._clock()
            alive = [b for b, until in c.workers.values() if until > now]
            return sorted(alive, key=lambda b: (-b.seen_at_s, b.worker_id))

    def close(self) -> None:
        """Nothing to release."""
