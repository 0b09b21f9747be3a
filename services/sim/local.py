"""The dispatch core with its state kept in memory: what the service does per epoch, without a store.

``LocalDispatcher`` commits with ``services.ledger.apply_decision``, the rule the stores apply
(docs/METHOD.md section 9), so a simulation run through it and one run through the HTTP service must give the
same decisions; the replay tests check this.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.dispatch import decide
from services.ledger import Ledger, apply_decision, dense_counts, ledger_view
from services.model import (
    IntervalKey,
    RiderId,
    RiderMatch,
    Snapshot,
    Task,
    TaskAssignment,
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
        self._ledger = Ledger()
        self._last_time_s: float | None = None

    def add_tasks(self, tasks: Sequence[Task]) -> None:
        """Register tasks (ids must be new)."""
        for t in tasks:
            if self._ledger.task(t.id) is not None:
                raise ValueError(f"task {t.id!r} is already registered")
            self._ledger.tasks[t.id] = t

    def epoch(self, snapshot: Snapshot) -> Outcome:
        """Decide one epoch and commit it."""
        if self._last_time_s is not None and snapshot.time_s < self._last_time_s:
            raise ValueError("epoch time is older than the last committed epoch")
        instrumented = (t.id for t in snapshot.taxis if t.instrumented)
        view = ledger_view(self._ledger, instrumented, self.city.grid.n_cells)
        started = time.perf_counter()
        decision = decide(self.city, view, snapshot, list(self._ledger.tasks.values()))
        solve_ms = (time.perf_counter() - started) * 1000.0
        apply_decision(self._ledger, decision.visits, decision.task_updates)
        self._last_time_s = snapshot.time_s
        return Outcome(
            decision.rider_matches, decision.task_assignments, decision.expired_rider_ids, solve_ms
        )

    def tasks(self) -> list[Task]:
        """Every registered task as it stands now."""
        return [*self._ledger.tasks.values(), *self._ledger.done.values()]

    def interval_counts(self, k: IntervalKey) -> NDArray[np.int64]:
        """Lambda over all cells for interval ``k`` (zeros when nothing was counted)."""
        return dense_counts(self._ledger.counts.get(k, {}), self.city.grid.n_cells)
