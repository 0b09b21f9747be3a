"""What committing an epoch changes, written once (docs/METHOD.md section 9).

The ``Ledger`` holds a city's grid counts Λ (sparse per interval), the (interval, cell) pairs each
instrumented taxi is already counted in, and the task records: the open ones (pending or assigned: what an
epoch reads) and the finished ones (completed or expired: history). ``apply_decision`` is the one commit
rule: a visit adds 1 to Λ_{g,t} (Eq. 1) only when its taxi is not yet counted in (g, t); a task update
replaces the stored record, and one that finishes the task moves it from the open set to the history, so an
epoch's cost depends on the open tasks only. The in-memory store and the in-process dispatcher apply it;
the Redis store's commit script implements the same rule in Lua and is tested against this function.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from services.model import DONE, CountsView, IntervalKey, Task, TaskId, TaxiId, Visit

__all__ = ["Ledger", "apply_decision", "dense_counts", "counts_view", "ledger_view"]


@dataclass(slots=True)
class Ledger:
    """One city's committed sensing state: ``counts[k][cell]`` is Λ (cells with a zero count absent),
    ``visits[(k, taxi)]`` the cells that taxi is counted in during interval ``k``, ``tasks`` the open tasks
    by id and ``done`` the finished ones."""

    counts: dict[IntervalKey, dict[int, int]] = field(default_factory=dict)
    visits: dict[tuple[IntervalKey, TaxiId], set[int]] = field(default_factory=dict)
    tasks: dict[TaskId, Task] = field(default_factory=dict)
    done: dict[TaskId, Task] = field(default_factory=dict)

    def task(self, task_id: TaskId) -> Task | None:
        """The record of a task, open or finished."""
        return self.tasks.get(task_id) or self.done.get(task_id)


def apply_decision(
    ledger: Ledger, visits: Iterable[Visit], task_updates: Iterable[Task]
) -> tuple[Visit, ...]:
    """Commit a decision's visits and task updates to ``ledger``; return the visits that counted.

    Each (taxi, interval, cell) is counted at most once ever: a visit the taxi already holds (from an earlier
    epoch or earlier in the same list) changes nothing. No I/O and no clock: the only effect is on ``ledger``.
    """
    counted: list[Visit] = []
    held, counts = ledger.visits, ledger.counts
    for v in visits:
        k, cell = IntervalKey(int(v.interval)), int(v.cell)
        key = (k, v.taxi_id)
        cells = held.get(key)
        if cells is None:  # (no empty set or dict built per visit only to be thrown away)
            cells = held[key] = set()
        elif cell in cells:
            continue
        cells.add(cell)
        row = counts.get(k)
        if row is None:
            row = counts[k] = {}
        row[cell] = row.get(cell, 0) + 1
        counted.append(v)
    for t in task_updates:
        if t.status in DONE:
            ledger.tasks.pop(t.id, None)
            ledger.done[t.id] = t
        else:
            ledger.tasks[t.id] = t
    return tuple(counted)


def dense_counts(sparse: Mapping[int, int], n_cells: int) -> NDArray[np.int64]:
    """Λ of one interval over all ``n_cells`` cells from its sparse form."""
    arr = np.zeros(n_cells, dtype=np.int64)
    if sparse:
        cells = np.fromiter(sparse.keys(), dtype=np.int64, count=len(sparse))
        arr[cells] = np.fromiter(sparse.values(), dtype=np.int64, count=len(sparse))
    return arr


def counts_view(
    counts: Mapping[IntervalKey, Mapping[int, int]],
    visited: Mapping[TaxiId, Iterable[tuple[IntervalKey, int]]],
    n_cells: int,
    intervals: Sequence[IntervalKey] | None = None,
) -> CountsView:
    """What ``decide`` reads: dense counts of ``intervals`` (default: every interval in ``counts``) and each
    taxi's counted (interval, cell) pairs."""
    keys = sorted(counts) if intervals is None else intervals
    return CountsView(
        counts={k: dense_counts(counts.get(k, {}), n_cells) for k in keys},
        visited={taxi: frozenset(pairs) for taxi, pairs in visited.items()},
    )


def ledger_view(ledger: Ledger, taxis: Iterable[TaxiId], n_cells: int) -> CountsView:
    """What ``decide`` reads of ``ledger`` for an epoch of the instrumented ``taxis``: every interval's counts
    and those taxis' counted (interval, cell) pairs."""
    wanted = set(taxis)
    visited: dict[TaxiId, set[tuple[IntervalKey, int]]] = {}
    for (k, taxi), cells in ledger.visits.items():
        if taxi in wanted:
            visited.setdefault(taxi, set()).update((k, c) for c in cells)
    return counts_view(ledger.counts, visited, n_cells)
