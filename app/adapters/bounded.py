"""``BoundedStore``: at most N calls in flight on the wrapped store; a call that finds no free slot within
``queue_s`` raises ``StoreUnavailable`` (a 503) at once.

Store calls are blocking and run on the threadpool's threads. When the store freezes (a Redis stopped with
SIGSTOP holds its connections and answers nothing), every call blocks until its socket timeout; without a
bound, a burst of readers takes every thread and the routes that never touch the store (a city's
description, the dashboard) queue behind them. With the bound only N threads wait; the rest answer 503 in
``queue_s``. Liveness (``/healthz``) runs on the event loop and needs no thread at all.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import TypeVar

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
    Store,
    StoredEpoch,
    StoreUnavailable,
    WorkerBeat,
)
from services.model import IntervalKey, Task, TaxiId

__all__ = ["BoundedStore"]

R = TypeVar("R")


class BoundedStore:
    """A ``Store`` that forwards to ``inner`` with at most ``concurrency`` calls in flight."""

    def __init__(self, inner: Store, concurrency: int, queue_s: float) -> None:
        if concurrency < 1 or queue_s < 0:
            raise ValueError("concurrency must be >= 1 and queue_s >= 0")
        self.inner = inner
        self.concurrency = concurrency
        self.queue_s = queue_s
        self._slots = threading.BoundedSemaphore(concurrency)

    @contextmanager
    def _slot(self) -> Iterator[None]:
        if not self._slots.acquire(timeout=self.queue_s):
            raise StoreUnavailable(
                f"all {self.concurrency} store slots are busy (waited {self.queue_s} s): the store is slow "
                "or frozen"
            )
        try:
            yield
        finally:
            self._slots.release()

    def _call(self, fn: Callable[[], R]) -> R:
        with self._slot():
            return fn()

    def ping(self) -> None:
        """Forwarded within a slot."""
        self._call(self.inner.ping)

    def get_epoch(self, city: str, epoch_id: str) -> StoredEpoch | None:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.get_epoch(city, epoch_id))

    def load_state(
        self,
        city: str,
        intervals: Sequence[IntervalKey],
        taxi_ids: Sequence[TaxiId],
        *,
        visits_from: IntervalKey | None = None,
    ) -> CityState:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.load_state(city, intervals, taxi_ids, visits_from=visits_from))

    def commit_epoch(self, city: str, commit: EpochCommit) -> CommitResult:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.commit_epoch(city, commit))

    def rewind_epochs(self, city: str, time_s: float) -> RewindResult:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.rewind_epochs(city, time_s))

    def reset_epochs(self, city: str) -> int:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.reset_epochs(city))

    def put_tasks(self, city: str, tasks: Sequence[Task]) -> PutTasksResult:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.put_tasks(city, tasks))

    def list_tasks(self, city: str) -> list[Task]:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.list_tasks(city))

    def interval_counts(self, city: str, interval: IntervalKey) -> dict[int, int]:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.interval_counts(city, interval))

    def list_intervals(self, city: str) -> list[IntervalKey]:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.list_intervals(city))

    def recorded_demand(self, city: str, day: str) -> list[str]:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.recorded_demand(city, day))

    def recorded_epochs(self, city: str, days: Sequence[str]) -> list[int]:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.recorded_epochs(city, days))

    def publish_recommendation(self, city: str, record: FleetRecord, history_limit: int) -> PublishResult:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.publish_recommendation(city, record, history_limit))

    def record_solve_failure(self, city: str, record: FleetRecord, history_limit: int) -> None:
        """Forwarded within a slot."""
        self._call(lambda: self.inner.record_solve_failure(city, record, history_limit))

    def current_recommendation(self, city: str) -> FleetRecord | None:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.current_recommendation(city))

    def recommendation_history(self, city: str, limit: int) -> list[FleetRecord]:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.recommendation_history(city, limit))

    def acquire_lock(self, city: str, name: str, ttl_s: float) -> str | None:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.acquire_lock(city, name, ttl_s))

    def release_lock(self, city: str, name: str, token: str) -> bool:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.release_lock(city, name, token))

    def enqueue_solve_request(self, city: str, request: SolveRequest) -> EnqueueResult:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.enqueue_solve_request(city, request))

    def claim_solve_request(self, city: str) -> SolveRequest | None:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.claim_solve_request(city))

    def pending_solve_request(self, city: str) -> SolveRequest | None:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.pending_solve_request(city))

    def record_worker_beat(self, city: str, beat: WorkerBeat, keep_s: float) -> None:
        """Forwarded within a slot."""
        self._call(lambda: self.inner.record_worker_beat(city, beat, keep_s))

    def worker_beats(self, city: str) -> list[WorkerBeat]:
        """Forwarded within a slot."""
        return self._call(lambda: self.inner.worker_beats(city))

    def close(self) -> None:
        """Close the wrapped store (no slot: closing must work while calls hang)."""
        self.inner.close()
