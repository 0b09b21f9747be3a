"""The store port: what the use cases need from persistence. Two adapters implement it
(``app.adapters.memory_store.MemoryStore`` and ``app.adapters.redis_store.RedisStore``) and pass one
contract suite (``tests/contract``)."""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field
from typing import Literal, Protocol
from zoneinfo import ZoneInfo

from app.errors import StoreUnavailable
from services.model import IntervalKey, Task, TaskId, TaxiId, Visit

__all__ = [
    "StoreUnavailable",
    "StoredEpoch",
    "CityState",
    "EpochCommit",
    "CommitResult",
    "RewindResult",
    "PutTasksResult",
    "FleetRecordStatus",
    "FleetRecord",
    "PublishStatus",
    "PublishResult",
    "SolveRequest",
    "EnqueueResult",
    "SolveProgress",
    "Waiting",
    "WorkerBeat",
    "Store",
    "local_day",
]


def local_day(time_s: float, timezone: str) -> str:
    """The calendar day of a POSIX time in ``timezone`` as ``YYYYMMDD``: the day an epoch's demand is
    recorded under (``EpochCommit.demand_day``, ``EpochStore.recorded_demand``)."""
    return dt.datetime.fromtimestamp(time_s, tz=ZoneInfo(timezone)).strftime("%Y%m%d")


@dataclass(frozen=True, slots=True)
class StoredEpoch:
    """A committed epoch's record; ``nonce`` is the commit attempt's (see ``EpochCommit``), when kept."""

    epoch_id: str
    body_hash: str
    time_s: float
    response_json: str
    nonce: str = ""


@dataclass(frozen=True, slots=True)
class CityState:
    """What a dispatch reads before solving one epoch.

    ``version`` counts committed epochs of the city; a commit names the version it was computed on.
    ``counts[k][cell]`` is Lambda (sparse: cells with a zero count are absent), for the intervals asked for.
    ``visited[taxi]`` holds the (interval, cell) pairs that taxi is already counted in, for the taxis and
    intervals asked for (a set or a frozen set, possibly the store's own: read it, never change it).
    ``tasks`` are the city's open tasks (pending or assigned): a finished task (completed or expired) is
    history, listed by ``list_tasks`` but never read by an epoch.
    """

    version: int
    last_epoch_id: str | None
    last_epoch_time_s: float | None
    counts: dict[IntervalKey, dict[int, int]]
    visited: Mapping[TaxiId, AbstractSet[tuple[IntervalKey, int]]]
    tasks: list[Task]


@dataclass(frozen=True, slots=True)
class EpochCommit:
    epoch_id: str
    body_hash: str
    time_s: float
    expected_version: int
    visits: Sequence[Visit]
    task_updates: Sequence[Task]
    response_json: str
    retention_s: int = 8 * 86400  # how long counts, visits and epoch records are kept
    demand_json: str | None = None  # the epoch's requests and fleet, recorded for the fleet-sizing worker
    demand_day: str = ""  # the city's local day of the epoch (``local_day``): where demand_json is recorded
    # Unique per commit attempt and stored with the record: when the store applied this very commit but
    # its reply was lost and the client library sent it again, the store finds its own nonce and answers
    # ``committed`` (not ``duplicate``), so the caller reports the commit it made.
    nonce: str = ""

    def __post_init__(self) -> None:
        if self.demand_json is not None and not self.demand_day:
            raise ValueError("recorded demand needs its day (demand_day)")


CommitStatus = Literal["committed", "duplicate", "version_mismatch", "stale"]


@dataclass(frozen=True, slots=True)
class CommitResult:
    """``committed``: everything applied. ``duplicate``: an epoch with that id exists (``stored`` holds
    it; nothing applied). ``version_mismatch``: another epoch committed since the state was read (nothing
    applied; reload and solve again). ``stale``: ``time_s`` is older than the last committed epoch."""

    status: CommitStatus
    stored: StoredEpoch | None = None
    new_version: int | None = None


RewindStatus = Literal["rewound", "empty", "ahead"]


@dataclass(frozen=True, slots=True)
class RewindResult:
    """``rewound``: the last epoch time is now the requested one. ``empty``: no epoch committed (nothing
    changed). ``ahead``: the requested time is later than the last epoch time (nothing changed).
    ``previous_time_s`` is the last epoch time before the call; ``version`` the committed epochs."""

    status: RewindStatus
    previous_time_s: float | None
    version: int


@dataclass(frozen=True, slots=True)
class PutTasksResult:
    """``conflicts`` lists ids that exist with different content; when it is non-empty nothing is written."""

    created: list[TaskId] = field(default_factory=list)
    unchanged: list[TaskId] = field(default_factory=list)
    conflicts: list[TaskId] = field(default_factory=list)


FleetRecordStatus = Literal["published", "failed"]


@dataclass(frozen=True, slots=True)
class FleetRecord:
    """One outcome of a fleet-sizing solve (docs/FLEET.md), as the current recommendation and the history
    keep it.

    ``published``: ``version`` (monotonic per city, 1, 2, ...) and ``body_json``, the recommendation
    document. ``failed``: ``reason``; nothing was published and the last good recommendation stays current.
    ``interval`` is the hour solved for (an ``IntervalKey``), ``request_id`` the admin request that asked
    for the solve (``None`` for the hourly schedule).
    """

    status: FleetRecordStatus
    computed_at_s: float
    interval: int
    version: int | None = None
    body_json: str | None = None
    reason: str | None = None
    request_id: str | None = None


PublishStatus = Literal["published", "version_mismatch"]


@dataclass(frozen=True, slots=True)
class PublishResult:
    """``published``: ``version`` is the new current version. ``version_mismatch``: the record's version is
    not the current one plus one (another solve published meanwhile); nothing written, ``version`` is the
    current one."""

    status: PublishStatus
    version: int


@dataclass(frozen=True, slots=True)
class SolveRequest:
    """An admin's request for a fleet-sizing solve now, queued for the worker."""

    request_id: str
    requested_at_s: float
    requested_by: str | None = None


@dataclass(frozen=True, slots=True)
class EnqueueResult:
    """``request`` is the pending request: the one just queued (``created``) or one already waiting, which
    the new one joins (a city has at most one pending request)."""

    request: SolveRequest
    created: bool


@dataclass(frozen=True, slots=True)
class SolveProgress:
    """A fleet solve in progress: the hour solved for, what asked for it, when it started and where its
    simulation runs stand (``runs_done`` of ``runs_total`` finished, ``runs_cached`` of them read from the
    cache, ``runs_failed`` of them raised; ``runs_running`` on a process now)."""

    interval: int
    trigger: Literal["schedule", "request"]
    request_id: str | None
    started_at_s: float
    runs_total: int = 0
    runs_done: int = 0
    runs_cached: int = 0
    runs_running: int = 0
    runs_failed: int = 0


@dataclass(frozen=True, slots=True)
class Waiting:
    """Why a worker cannot size a city now (``kind``: ``insufficient_history`` or ``no_tasks``) since when;
    it starts no run for the city until that changes."""

    kind: str
    reason: str
    since_s: float


@dataclass(frozen=True, slots=True)
class WorkerBeat:
    """One fleet worker's heartbeat for one city (docs/FLEET.md, "Heartbeat and status").

    ``worker_id`` names the worker (host, process and a random suffix); ``seen_at_s`` is when it wrote the
    beat (POSIX seconds); ``embedded`` tells a worker inside the API process (``python -m app run`` on the
    memory store) from a ``python -m app worker`` process. ``solving`` is the city's solve in progress, if
    any; ``next_interval`` the hour of the next scheduled solve, due at ``next_due_at_s``; ``waiting`` why
    the city cannot be sized now, if it cannot.
    """

    worker_id: str
    seen_at_s: float
    started_at_s: float
    host: str
    pid: int
    embedded: bool
    poll_s: float
    solving: SolveProgress | None = None
    next_interval: int | None = None
    next_due_at_s: float | None = None
    waiting: Waiting | None = None


class EpochStore(Protocol):
    """Epochs and counts: the idempotent epoch records, the consistent state an epoch is solved on, the
    atomic commit, the counts per interval and the demand recorded with each epoch."""

    def ping(self) -> None:
        """Raise ``StoreUnavailable`` when the store cannot be reached."""

    def get_epoch(self, city: str, epoch_id: str) -> StoredEpoch | None: ...

    def load_state(
        self,
        city: str,
        intervals: Sequence[IntervalKey],
        taxi_ids: Sequence[TaxiId],
        *,
        visits_from: IntervalKey | None = None,
    ) -> CityState:
        """Version, last epoch, the counts of ``intervals``, the (interval, cell) pairs each of ``taxi_ids``
        is counted in during those of ``intervals`` from ``visits_from`` on (all of them with None: a
        decision reads no earlier pair), and the tasks, as one consistent snapshot."""

    def commit_epoch(self, city: str, commit: EpochCommit) -> CommitResult:
        """Atomically: check id unseen (or seen with this commit's nonce: ``committed`` again, nothing
        applied twice), version == expected, time >= last; then apply visits (each (taxi, interval, cell)
        counted at most once ever: Lambda += 1 only for a new member), upsert the task updates, store the
        epoch record and bump the version. The city's meta (version, last epoch) lives as long as the
        retention after the last commit, like everything else the commit writes."""

    def interval_counts(self, city: str, interval: IntervalKey) -> dict[int, int]: ...

    def list_intervals(self, city: str) -> list[IntervalKey]:
        """Intervals with at least one count, ascending."""

    def recorded_demand(self, city: str, day: str) -> list[str]:
        """The ``demand_json`` of the epochs committed with ``demand_day`` ``day`` (``YYYYMMDD``, the city's
        local day), in commit order."""

    def recorded_epochs(self, city: str, days: Sequence[str]) -> list[int]:
        """How many epochs recorded demand on each of ``days`` (as ``recorded_demand`` keys them), without
        reading the records."""


class TaskStore(Protocol):
    """The monitoring tasks of a city (an epoch's commit updates them too)."""

    def put_tasks(self, city: str, tasks: Sequence[Task]) -> PutTasksResult:
        """Register tasks, idempotent per id (same content: unchanged; different content: conflict)."""

    def list_tasks(self, city: str) -> list[Task]: ...


class AdminStore(Protocol):
    """Rewinding or resetting a city's epoch stream."""

    def rewind_epochs(self, city: str, time_s: float) -> RewindResult:
        """Atomically set the city's last epoch time back to ``time_s`` (epochs at or after it are accepted
        again); what committed epochs wrote stays."""

    def reset_epochs(self, city: str) -> int:
        """Delete the city's epoch stream (meta, epoch records, counts, visits, intervals, recorded demand,
        tasks); fleet-sizing records and locks stay. Returns how many entries were deleted."""


class FleetStore(Protocol):
    """Fleet sizing (docs/FLEET.md): the published recommendation and its history, the solve locks, the
    queued solve requests and the workers' heartbeats."""

    def publish_recommendation(self, city: str, record: FleetRecord, history_limit: int) -> PublishResult:
        """Atomically, if ``record.version`` is the current version plus one (0 when none): make ``record``
        (status ``published``) the current recommendation and push it on the history, which keeps the
        newest ``history_limit`` entries."""

    def record_solve_failure(self, city: str, record: FleetRecord, history_limit: int) -> None:
        """Push a ``failed`` record on the history (bounded as above); the current recommendation stays."""

    def current_recommendation(self, city: str) -> FleetRecord | None:
        """The last published recommendation, if any."""

    def recommendation_history(self, city: str, limit: int) -> list[FleetRecord]:
        """Up to ``limit`` history entries (published and failed), newest first."""

    def acquire_lock(self, city: str, name: str, ttl_s: float) -> str | None:
        """Take the lock ``name`` of the city for ``ttl_s`` seconds unless someone holds it: a fresh token,
        or ``None`` when it is held (Redis ``SET NX PX``)."""

    def release_lock(self, city: str, name: str, token: str) -> bool:
        """Release the lock if ``token`` still holds it (never another holder's); whether it did."""

    def enqueue_solve_request(self, city: str, request: SolveRequest) -> EnqueueResult:
        """Queue a solve request unless one is pending (then that one is returned, ``created=False``)."""

    def claim_solve_request(self, city: str) -> SolveRequest | None:
        """Take the pending request off the queue (exactly one claimant gets it), if any."""

    def pending_solve_request(self, city: str) -> SolveRequest | None:
        """The pending request, if any, left on the queue."""

    def record_worker_beat(self, city: str, beat: WorkerBeat, keep_s: float) -> None:
        """Record ``beat`` as its worker's latest for the city (replacing that worker's previous one). Beats
        of any worker seen more than ``keep_s`` before this one are dropped, and the city's beats are
        forgotten ``keep_s`` after the last one written."""

    def worker_beats(self, city: str) -> list[WorkerBeat]:
        """The latest beat of every worker the city keeps, newest first."""


class DispatchStore(EpochStore, TaskStore, Protocol):
    """What the epoch use cases read and write (``app.usecases.EpochService``): the epoch stream and its
    counts, and the tasks an epoch assigns."""


class StreamStore(EpochStore, AdminStore, Protocol):
    """What the admin use cases read and write (``app.usecases.AdminService``): the epoch stream they rewind
    or reset."""


class WorkerStore(FleetStore, TaskStore, EpochStore, Protocol):
    """What the fleet worker's use cases read and write (``app.usecases.fleet_solve.FleetSolver``): its
    records, locks, requests and beats, the registered tasks and the demand recorded with the epochs."""


class Store(EpochStore, TaskStore, AdminStore, FleetStore, Protocol):
    """The whole store: every part above (each adapter implements them all) and closing it. A use case
    asks for the part it uses."""

    def close(self) -> None: ...
