"""The fleet worker's use cases (docs/FLEET.md): the solve requests it takes, the inputs it reads (the
platform's registered tasks, the demand recorded with the epochs), publishing a recommendation under the
hour's lock, and its heartbeat. The worker (``app.worker``) decides when to solve and runs the
simulations; what it reads and writes goes through here, as the API's does through the other use cases."""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterator
from contextlib import contextmanager
from zoneinfo import ZoneInfo

from app.ports import FleetRecord, PublishResult, SolveRequest, WorkerBeat, WorkerStore, utc_day
from services.city import City
from services.model import IntervalKey, Task

__all__ = ["SizingService", "lock_name"]


def lock_name(interval: int) -> str:
    """The store lock of one hour's solve."""
    return f"fleet-solve:{int(interval)}"


class SizingService:
    """What the fleet worker reads and writes. ``history_limit`` bounds a city's recommendation history;
    ``lock_ttl_s`` is how long an hour's lock outlives a worker that died holding it."""

    def __init__(self, store: WorkerStore, *, history_limit: int = 100, lock_ttl_s: float = 1800.0) -> None:
        self.store = store
        self.history_limit = history_limit
        self.lock_ttl_s = lock_ttl_s

    # ------------------------------------------------------------------ requests

    def claim_request(self, city: str) -> SolveRequest | None:
        """Take the city's pending admin request off the queue, if any (exactly one worker gets it)."""
        return self.store.claim_solve_request(city)

    def requeue(self, city: str, request: SolveRequest) -> None:
        """Put a claimed request back for the next poll (another worker holds the hour's lock)."""
        self.store.enqueue_solve_request(city, request)

    # ------------------------------------------------------------------ inputs

    def registered_tasks(self, city: str) -> list[Task]:
        """The platform's registered tasks of the city, in scheduled order."""
        return sorted(self.store.list_tasks(city), key=lambda t: (t.scheduled_at_s, str(t.id)))

    def recorded_day(self, city: City, day: dt.date) -> list[str]:
        """The demand documents recorded with the epochs of the UTC days that overlap local ``day`` (the
        store keys them by UTC day; ``app.worker.recorded`` keeps the riders of ``day`` itself)."""
        tz = ZoneInfo(city.horizon.timezone)
        start = dt.datetime.combine(day, dt.time(0), tzinfo=tz).timestamp()
        end = dt.datetime.combine(day + dt.timedelta(days=1), dt.time(0), tzinfo=tz).timestamp() - 1.0
        keys = list(dict.fromkeys((utc_day(start), utc_day(end))))
        return [text for key in keys for text in self.store.recorded_demand(city.name, key)]

    # ------------------------------------------------------------------ publishing

    @contextmanager
    def hour_lock(self, city: str, target: IntervalKey) -> Iterator[bool]:
        """Hold the lock of hour ``target``'s solve for the block: yields whether it was taken (``False``:
        another worker holds it, and nothing is to be written)."""
        token = self.store.acquire_lock(city, lock_name(target), self.lock_ttl_s)
        try:
            yield token is not None
        finally:
            if token is not None:
                self.store.release_lock(city, lock_name(target), token)

    def current(self, city: str) -> FleetRecord | None:
        """The city's current recommendation, if any."""
        return self.store.current_recommendation(city)

    def publish(self, city: str, record: FleetRecord) -> PublishResult:
        """Publish ``record`` as the city's recommendation if its version is the next one."""
        return self.store.publish_recommendation(city, record, self.history_limit)

    def record_failure(self, city: str, record: FleetRecord) -> None:
        """Keep a failed solve in the history; the current recommendation stays."""
        self.store.record_solve_failure(city, record, self.history_limit)

    # ------------------------------------------------------------------ heartbeat

    def beat(self, city: str, beat: WorkerBeat, keep_s: float) -> None:
        """Record the worker's latest beat for the city (beats older than ``keep_s`` are dropped)."""
        self.store.record_worker_beat(city, beat, keep_s)
