"""Response model of ``GET /v1/cities/{city}/fleet/status`` (docs/FLEET.md, "Heartbeat and status"): the
fleet worker's last heartbeat, the solve in progress with its runs, the pending request, the last solve and
the next scheduled one."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from app.ports import WorkerBeat
from app.schemas.common import HistoryCountOut, ResponseModel
from app.schemas.fleet import SolveEntryOut
from app.usecases import FleetStatus
from services.city import Horizon
from services.rfc3339 import format_time

__all__ = [
    "WorkerOut",
    "WorkerStateOut",
    "SolvingOut",
    "PendingRequestOut",
    "LastSolveOut",
    "NextSolveOut",
    "HistoryOut",
    "WaitingOut",
    "FleetStatusOut",
]


class WorkerOut(ResponseModel):
    """One fleet worker serving the city, by its latest heartbeat."""

    id: str = Field(description="Host, process id and a random suffix.")
    host: str
    pid: int
    embedded: bool = Field(description="Inside the API process (`python -m app run` on the memory store).")
    started_at: str = Field(description="When the worker started, RFC 3339 in the city's time zone.")
    last_heartbeat: str
    heartbeat_age_s: float = Field(description="Seconds since its last heartbeat.")
    live: bool = Field(description="Seen within stale_after_s.")
    poll_s: float = Field(description="How often it polls the solve queue.")


class WorkerStateOut(ResponseModel):
    """Whether a worker is there to answer a solve request."""

    seen: bool = Field(description="A worker serving the city was seen within stale_after_s.")
    last_heartbeat: str | None = Field(description="The newest heartbeat kept (null: none).")
    heartbeat_age_s: float | None
    stale_after_s: float
    workers: list[WorkerOut] = Field(description="Every worker kept, newest heartbeat first.")
    hint: str | None = Field(description="How to start a worker, when none is seen.")


class SolvingOut(ResponseModel):
    """The solve in progress and its simulation runs ("solving: k of n runs")."""

    interval: str = Field(description="The hour solved for, YYYY-MM-DDTHH:MM.")
    trigger: Literal["schedule", "request"]
    request_id: str | None
    started_at: str
    elapsed_s: float
    runs_total: int
    runs_done: int = Field(description="Finished, cached ones included.")
    runs_cached: int
    runs_running: int
    runs_failed: int
    worker: str


class PendingRequestOut(ResponseModel):
    """A solve request waiting for the worker to claim it."""

    request_id: str
    requested_at: str


class LastSolveOut(SolveEntryOut):
    """The newest entry of the history."""


class NextSolveOut(ResponseModel):
    """The next scheduled solve of a live worker."""

    interval: str = Field(description="The hour it will solve for.")
    due_at: str = Field(description="When the solve is due (the hour's start minus SD_WORKER_LEAD_S).")


class HistoryOut(HistoryCountOut):
    """The history a solve today would be sized on."""

    enough: bool = Field(description="A solve today has its M days.")
    until_then: Literal["synthetic", "none"] = Field(
        description="With fewer days: synthetic (a demo city is sized on its generator's seeded days) or "
        "none (the city is not sized: POST .../fleet/solve answers 409 insufficient_history)."
    )
    text: str = Field(description='"collecting history: k of M days ..." or "history complete: ..."')


class WaitingOut(ResponseModel):
    """Why the worker does not size the city now (it starts no run until that changes)."""

    kind: str = Field(description="insufficient_history or no_tasks.")
    reason: str
    since: str = Field(description="Since when, RFC 3339 in the city's time zone.")


class FleetStatusOut(ResponseModel):
    """The fleet worker as the city sees it."""

    city: str
    now: str
    worker: WorkerStateOut
    history: HistoryOut
    waiting: WaitingOut | None = Field(
        description="Why the live worker does not size the city (null: it does)."
    )
    solving: SolvingOut | None
    pending_request: PendingRequestOut | None
    last_solve: LastSolveOut | None
    next_scheduled: NextSolveOut | None

    @classmethod
    def of(cls, st: FleetStatus, hint: str) -> FleetStatusOut:
        """From the use case's status."""
        hz, tz, now = st.city.horizon, st.city.horizon.timezone, st.now_s
        live = st.live

        def worker(b: WorkerBeat) -> WorkerOut:
            return WorkerOut(
                id=b.worker_id,
                host=b.host,
                pid=b.pid,
                embedded=b.embedded,
                started_at=format_time(b.started_at_s, tz),
                last_heartbeat=format_time(b.seen_at_s, tz),
                heartbeat_age_s=round(max(0.0, now - b.seen_at_s), 3),
                live=b in live,
                poll_s=b.poll_s,
            )

        newest = st.beats[0] if st.beats else None
        state = WorkerStateOut(
            seen=bool(live),
            last_heartbeat=None if newest is None else format_time(newest.seen_at_s, tz),
            heartbeat_age_s=None if newest is None else round(max(0.0, now - newest.seen_at_s), 3),
            stale_after_s=st.stale_after_s,
            workers=[worker(b) for b in st.beats],
            hint=None if live else hint,
        )
        solving = next((b for b in live if b.solving is not None), None)
        scheduled = sorted(
            (b for b in live if b.next_due_at_s is not None), key=lambda b: b.next_due_at_s or 0
        )
        last, pending = st.last, st.pending
        waiting = next((b.waiting for b in live if b.waiting is not None), None)
        h = st.history
        return cls(
            city=st.city.name,
            now=format_time(now, tz),
            worker=state,
            history=HistoryOut(
                days=h.days,
                needed=h.needed,
                first_solve_on=h.first_solve_on.isoformat(),
                enough=h.enough,
                until_then="synthetic" if st.city.fleet.synthetic_history else "none",
                text=h.describe(),
            ),
            waiting=None
            if waiting is None
            else WaitingOut(kind=waiting.kind, reason=waiting.reason, since=format_time(waiting.since_s, tz)),
            solving=None if solving is None else _solving(solving, now, hz),
            pending_request=None
            if pending is None
            else PendingRequestOut(
                request_id=pending.request_id, requested_at=format_time(pending.requested_at_s, tz)
            ),
            last_solve=None if last is None else LastSolveOut.of(last, hz),
            next_scheduled=None
            if not scheduled or scheduled[0].next_interval is None or scheduled[0].next_due_at_s is None
            else NextSolveOut(
                interval=hz.label(scheduled[0].next_interval),
                due_at=format_time(scheduled[0].next_due_at_s, tz),
            ),
        )


def _solving(b: WorkerBeat, now: float, hz: Horizon) -> SolvingOut:
    """The beat's solve in progress as served."""
    p = b.solving
    assert p is not None
    tz = hz.timezone
    return SolvingOut(
        interval=hz.label(p.interval),
        trigger=p.trigger,
        request_id=p.request_id,
        started_at=format_time(p.started_at_s, tz),
        elapsed_s=round(max(0.0, now - p.started_at_s), 3),
        runs_total=p.runs_total,
        runs_done=p.runs_done,
        runs_cached=p.runs_cached,
        runs_running=p.runs_running,
        runs_failed=p.runs_failed,
        worker=b.worker_id,
    )
