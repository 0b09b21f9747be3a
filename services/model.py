"""Plain data types shared by the core: riders, taxis, tasks, epoch snapshots and decisions.

Node references inside the core are *indices* into ``Network`` arrays (``int``), never external ids;
the shell converts ids and lon/lat to indices at the edge. Times are POSIX seconds (``float``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, NewType

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "TaxiId",
    "RiderId",
    "TaskId",
    "IntervalKey",
    "Visit",
    "Rider",
    "Taxi",
    "Task",
    "TaskStatus",
    "DONE",
    "CompletionMode",
    "Snapshot",
    "CountsView",
    "RiderMatch",
    "TaskAssignment",
    "Decision",
]

TaxiId = NewType("TaxiId", str)
RiderId = NewType("RiderId", str)
TaskId = NewType("TaskId", str)
IntervalKey = NewType("IntervalKey", int)
"""Global sensing-interval number: floor((local time - horizon start) / interval length); ``city.Horizon``."""

TaskStatus = Literal["pending", "assigned", "completed", "expired"]
DONE: frozenset[str] = frozenset({"completed", "expired"})
"""Statuses that end a task: it leaves the set an epoch reads (the stores keep it as history)."""
CompletionMode = Literal["passive", "active"]


@dataclass(frozen=True, slots=True)
class Visit:
    """One (taxi, interval, cell) crossing: the unit that Lambda counts, at most once each."""

    taxi_id: TaxiId
    interval: IntervalKey
    cell: int


@dataclass(frozen=True, slots=True)
class Rider:
    id: RiderId
    origin: int
    destination: int
    requested_at_s: float


@dataclass(frozen=True, slots=True)
class Taxi:
    id: TaxiId
    node: int
    instrumented: bool
    vacant: bool


@dataclass(frozen=True, slots=True)
class Task:
    """A monitoring task: POI node and scheduled time, plus its lifecycle (docs/METHOD.md section 6).

    ``assigned``: an instrumented taxi's committed path reaches ``node`` at ``completed_at_s`` (in the
    future of the committing epoch). ``completed``: that time has passed (as of a committed epoch).
    ``expired``: still pending when its scheduled time fell out of the service's retention window.
    """

    id: TaskId
    node: int
    scheduled_at_s: float
    status: TaskStatus = "pending"
    completed_at_s: float | None = None
    taxi_id: TaxiId | None = None
    mode: CompletionMode | None = None
    location: tuple[float, float] | None = None  # (lon, lat) as registered, if given that way

    def is_open(self, time_s: float) -> bool:
        return self.status == "pending" and self.scheduled_at_s <= time_s


@dataclass(frozen=True, slots=True)
class Snapshot:
    """What the platform posts for one decision epoch, already resolved to node indices."""

    epoch_id: str
    time_s: float
    riders: tuple[Rider, ...]
    taxis: tuple[Taxi, ...]


@dataclass(frozen=True, slots=True)
class CountsView:
    """Grid counts as of the start of an epoch (read-only for the solver).

    ``counts[k]`` is Lambda over all grid cells for interval ``k`` (int array of length ``n_cells``);
    intervals absent from the mapping are taken as all-zero and reported in ``Decision.intervals_touched``
    so the caller can check it loaded every interval the decision reached.
    ``visited[taxi]`` holds the (interval, cell) pairs in which that taxi is already counted.
    """

    counts: dict[IntervalKey, NDArray[np.int64]]
    visited: dict[TaxiId, frozenset[tuple[IntervalKey, int]]] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class RiderMatch:
    step: Literal[1, 2]
    taxi_id: TaxiId
    rider_id: RiderId
    pickup_m: float
    wait_s: float
    trip_m: float
    trip_time_s: float
    sensing_gain: float
    path: tuple[int, ...]  # node indices, taxi -> pickup -> dropoff
    cells: tuple[tuple[int, int], ...]  # G-route of the whole path, (col, row), in order of first entry


@dataclass(frozen=True, slots=True)
class TaskAssignment:
    taxi_id: TaxiId
    task_id: TaskId
    path: tuple[int, ...]
    cells: tuple[tuple[int, int], ...]
    length_m: float
    travel_time_s: float
    sensing_gain: float
    efficiency: float  # phi = sensing_gain / travel_time_s, Eq. (12)
    cost_cny: float
    kappa: float


@dataclass(frozen=True, slots=True)
class Decision:
    """The outcome of one epoch: matches, monitoring routes, task changes and the visits to count."""

    epoch_id: str
    time_s: float
    rider_matches: tuple[RiderMatch, ...]
    task_assignments: tuple[TaskAssignment, ...]
    tasks_completed: tuple[Task, ...]  # tasks whose completion time is <= this epoch's time, newly so
    task_updates: tuple[Task, ...]  # every task whose stored record changes on commit
    unmatched_rider_ids: tuple[RiderId, ...]
    expired_rider_ids: tuple[RiderId, ...]  # waited longer than patience: dropped, not matched
    visits: tuple[Visit, ...]  # distinct (taxi, interval, cell) crossings of instrumented planned paths
    intervals_touched: tuple[IntervalKey, ...]
    stats: dict[str, float | int]

    @property
    def matches_by_step(self) -> dict[int, int]:
        """How many riders Step 1 and Step 2 matched (``{1: n1, 2: n2}``): the counts ``decide`` keeps in
        ``stats`` as ``step1_matches`` and ``step2_matches``, the one count of them an epoch makes."""
        return {1: int(self.stats["step1_matches"]), 2: int(self.stats["step2_matches"])}
