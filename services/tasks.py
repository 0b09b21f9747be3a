"""Monitoring-task lifecycle (docs/METHOD.md section 6): which planned paths reach which POIs, and when.

A pending task is taken by the first instrumented taxi whose committed path reaches its node at or after
its scheduled time: ``assigned`` until that moment, ``completed`` once an epoch at or after it commits.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.model import CompletionMode, Task, TaskId, TaskStatus, TaxiId

__all__ = ["PlannedPath", "Reach", "node_arrivals", "reaches", "apply_reaches", "due_completions"]


@dataclass(frozen=True, slots=True)
class PlannedPath:
    """An instrumented taxi's committed path this epoch; ``target_task`` is set for a Step 3 route."""

    taxi_id: TaxiId
    start: int
    edges: NDArray[np.int64]
    depart_s: float
    target_task: TaskId | None = None


@dataclass(frozen=True, slots=True)
class Reach:
    task_id: TaskId
    taxi_id: TaxiId
    at_s: float
    mode: CompletionMode


def node_arrivals(city: City, path: PlannedPath) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Nodes along the path (start included) and the time the taxi is at each."""
    net = city.network
    nodes = np.concatenate(([path.start], net.edge_v[path.edges])).astype(np.int64)
    times = path.depart_s + np.concatenate(([0.0], np.cumsum(net.edge_time_s[path.edges])))
    return nodes, times


def reaches(city: City, paths: Iterable[PlannedPath], tasks: Sequence[Task]) -> dict[TaskId, Reach]:
    """For each pending task, the earliest arrival of a planned path at its node at or after its
    scheduled time (ties: an active arrival wins). The target of a Step 3 route counts as ``active``."""
    pending: dict[int, list[Task]] = {}
    for task in tasks:
        if task.status == "pending":
            pending.setdefault(task.node, []).append(task)
    best: dict[TaskId, Reach] = {}
    if not pending:
        return best
    at_task = np.zeros(city.network.n_nodes, dtype=bool)
    at_task[np.fromiter(pending, dtype=np.int64)] = True
    for path in paths:
        nodes, times = node_arrivals(city, path)
        for i in np.flatnonzero(at_task[nodes]):
            for task in pending[int(nodes[i])]:
                at = float(times[i])
                if at < task.scheduled_at_s:
                    continue
                mode: CompletionMode = "active" if path.target_task == task.id else "passive"
                cur = best.get(task.id)
                if (
                    cur is None
                    or at < cur.at_s
                    or (at == cur.at_s and mode == "active" and cur.mode != "active")
                ):
                    best[task.id] = Reach(task.id, path.taxi_id, at, mode)
    return best


def apply_reaches(tasks: Sequence[Task], found: dict[TaskId, Reach], now_s: float) -> list[Task]:
    """Tasks updated by ``found``: assigned to the taxi, or completed if the arrival is not in the future."""
    out = []
    for task in tasks:
        r = found.get(task.id)
        if r is None:
            continue
        status: TaskStatus = "completed" if r.at_s <= now_s else "assigned"
        out.append(
            dataclasses.replace(task, status=status, completed_at_s=r.at_s, taxi_id=r.taxi_id, mode=r.mode)
        )
    return out


def due_completions(tasks: Sequence[Task], now_s: float) -> list[Task]:
    """Assigned tasks whose arrival time has come by ``now_s``: they become completed."""
    return [
        dataclasses.replace(t, status="completed")
        for t in tasks
        if t.status == "assigned" and t.completed_at_s is not None and t.completed_at_s <= now_s
    ]
