"""The dispatch core with its state kept in memory: what the service does per epoch, without a store.

``LocalDispatcher`` commits with ``services.ledger.apply_decision``, the rule the stores apply
(docs/METHOD.md section 9), so a simulation run through it and one run through the HTTP service must give the
same decisions; the replay tests check this.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.dispatch import decide
from services.ledger import Ledger, apply_decision, dense_counts
from services.model import (
    CountsView,
    IntervalKey,
    RiderId,
    RiderMatch,
    Snapshot,
    Task,
    TaskAssignment,
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
    """``services.dispatch.decide`` plus an in-memory copy of the state the service keeps for one city.

    ``phase``, a benchmark's stopwatch, is called with "view" once the epoch's counts are read, then by
    ``decide`` as each of its phases ends, and with "commit" once the decision is committed."""

    def __init__(self, city: City, phase: Callable[[str], None] | None = None) -> None:
        self.city = city
        self._ledger = Ledger()
        self._last_time_s: float | None = None
        self._phase = phase
        self._visited: dict[TaxiId, frozenset[tuple[IntervalKey, int]]] = {}  # the ledger's, per taxi

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
        view = self.counts_view(t.id for t in snapshot.taxis if t.instrumented)
        lap = self._phase or _no_lap
        lap("view")
        started = time.perf_counter()
        decision = decide(self.city, view, snapshot, list(self._ledger.tasks.values()), phase=self._phase)
        solve_ms = (time.perf_counter() - started) * 1000.0
        counted = apply_decision(self._ledger, decision.visits, decision.task_updates)
        fresh: dict[TaxiId, set[tuple[IntervalKey, int]]] = {}
        for v in counted:
            fresh.setdefault(v.taxi_id, set()).add((IntervalKey(int(v.interval)), int(v.cell)))
        for taxi, pairs in fresh.items():
            self._visited[taxi] = self._visited.get(taxi, frozenset()) | pairs
        lap("commit")
        self._last_time_s = snapshot.time_s
        return Outcome(
            decision.rider_matches, decision.task_assignments, decision.expired_rider_ids, solve_ms
        )

    def counts_view(self, taxis: Iterable[TaxiId]) -> CountsView:
        """What ``decide`` reads for an epoch of the instrumented ``taxis``: ``services.ledger.ledger_view``
        of the ledger, its per-taxi pairs kept up to date at each commit instead of gathered every epoch."""
        n_cells = self.city.grid.n_cells
        counts = self._ledger.counts
        visited = {t: pairs for t in taxis if (pairs := self._visited.get(t)) is not None}
        return CountsView({k: dense_counts(counts[k], n_cells) for k in sorted(counts)}, visited)

    @property
    def ledger(self) -> Ledger:
        """The committed state (read it, do not change it)."""
        return self._ledger

    def tasks(self) -> list[Task]:
        """Every registered task as it stands now."""
        return [*self._ledger.tasks.values(), *self._ledger.done.values()]

    def interval_counts(self, k: IntervalKey) -> NDArray[np.int64]:
        """Lambda over all cells for interval ``k`` (zeros when nothing was counted)."""
        return dense_counts(self._ledger.counts.get(k, {}), self.city.grid.n_cells)


def _no_lap(_name: str) -> None:
    return None
