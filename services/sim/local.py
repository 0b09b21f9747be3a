"""The dispatch core with its state kept in memory: what the service does per epoch, without a store.

``LocalDispatcher`` applies exactly the commit of METHOD section 9 (Lambda + 1 per new visit, the taxi's
(interval, cell) pairs remembered, task records replaced by the decision's updates), so a simulation run
through it and one run through the HTTP service must give the same decisions; the replay tests check this.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.dispatch import decide
from services.model import (
    CountsView,
    IntervalKey,
    RiderId,
    RiderMatch,
    Snapshot,
    Task,
    TaskAssignment,
    TaskId,
    TaxiId,
)

__all__ = ["Outcome", "LocalDispatcher"]


@dataclass(frozen=True, slots=True)
class Outcome:
    """What a simulator needs back from one epoch, however it was decided."""

    rider_matches: tuple[RiderMatch, ...]
    task_assignments: tuple[TaskAssignment, ...]
    expired_rider_ids: tuple[RiderId, ...]
    solve_ms: float


class LocalDispatcher:
    """``services.dispatch.decide`` plus an in-memory copy of the state the service keeps for one city."""

    def __init__(self, city: City) -> None:
        self.city = city
        self._counts: dict[IntervalKey, NDArray[np.int64]] = {}
        self._visited: dict[TaxiId, set[tuple[IntervalKey, int]]] = {}
        self._tasks: dict[TaskId, Task] = {}
        self._last_time_s: float | None = None

    def add_tasks(self, tasks: Sequence[Task]) -> None:
        """Register tasks (ids must be new)."""
        for t in tasks:
            if t.id in self._tasks:
                raise ValueError(f"task {t.id!r} is already registered")
            self._tasks[t.id] = t

    def epoch(self, snapshot: Snapshot) -> Outcome:
        """Decide one epoch and commit it."""
        if self._last_time_s is not None and snapshot.time_s < self._last_time_s:
            raise ValueError("epoch time is older than the last committed epoch")
        instrumented = {t.id for t in snapshot.taxis if t.instrumented}
        view = CountsView(
            counts=self._counts,
            visited={taxi: frozenset(pairs) for taxi, pairs in self._visited.items() if taxi in instrumented},
        )
        started = time.perf_counter()
        decision = decide(self.city, view, snapshot, list(self._tasks.values()))
        solve_ms = (time.perf_counter() - started) * 1000.0
        n_cells = self.city.grid.n_cells
        for v in decision.visits:
            arr = self._counts.get(v.interval)
            if arr is None:
                arr = self._counts[v.interval] = np.zeros(n_cells, dtype=np.int64)
            arr[v.cell] += 1
            self._visited.setdefault(v.taxi_id, set()).add((v.interval, v.cell))
        for t in decision.task_updates:
            self._tasks[t.id] = t
        self._last_time_s = snapshot.time_s
        return Outcome(
            decision.rider_matches, decision.task_assignments, decision.expired_rider_ids, solve_ms
        )

    def tasks(self) -> list[Task]:
        """Every registered task as it stands now."""
        return list(self._tasks.values())

    def interval_counts(self, k: IntervalKey) -> NDArray[np.int64]:
        """Lambda over all cells for interval ``k`` (zeros when nothing was counted)."""
        arr = self._counts.get(k)
        return np.zeros(self.city.grid.n_cells, dtype=np.int64) if arr is None else arr.copy()
