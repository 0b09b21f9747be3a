"""Fleet-sizing routes: the worker's current recommendation, its history and its status (scope `read`), and a
request for a solve now (scope `admin`; queued for the worker, never solved inside the request, and refused
when no worker is there to solve it). docs/FLEET.md."""

from __future__ import annotations

import uuid
from typing import Annotated

from fastapi import APIRouter, Query
from pydantic import ValidationError

from app.api.deps import AdminAccess, CityName, FleetDep, ReadAccess
from app.api.responses import READ_ERRORS, errors
from app.errors import InternalError
from app.ports import FleetRecord
from app.schemas.fleet import FleetHistoryEntryOut, FleetHistoryOut, FleetRecommendationOut, SolveRequestOut
from app.schemas.fleet_status import FleetStatusOut
from app.usecases import START_WORKER_HINT
from services.rfc3339 import format_time

__all__ = ["router", "AdminAccess"]

router = APIRouter(prefix="/v1/cities", tags=["fleet"])

HISTORY_MAX = 100


def _recommendation(record: FleetRecord, timezone: str) -> FleetRecommendationOut:
    """A published record as served; a document this version cannot read is an internal error."""
    try:
        return FleetRecommendationOut.of(record, timezone)
    except (ValidationError, ValueError, TypeError) as exc:
        raise InternalError(f"stored recommendation version {record.version} cannot be read: {exc}") from exc


@router.get(
    "/{city}/fleet/recommendation",
    response_model=FleetRecommendationOut,
    summary="Current fleet-size recommendation",
    responses=READ_ERRORS,
)
def get_recommendation(city: CityName, _: ReadAccess, fleet: FleetDep) -> FleetRecommendationOut:
    """The worker's latest published recommendation: the chosen size per method (Deterministic, DRO, DRO_RH
    for the coming hour, the completion target), the per-size tables (mean, worst case, premium, rho, m),
    divergence, alpha, the data window, computed_at and version. 404 `no_data` before the first solve."""
    served, record = fleet.recommendation(city)
    return _recommendation(record, served.horizon.timezone)


@router.get(
    "/{city}/fleet/recommendations",
    response_model=FleetHistoryOut,
    summary="Recommendation history",
    responses=READ_ERRORS,
)
def list_recommendations(
    city: CityName,
    _: ReadAccess,
    fleet: FleetDep,
    limit: Annotated[int, Query(ge=1, le=HISTORY_MAX, description="Most entries to return.")] = 20,
) -> FleetHistoryOut:
    """Solves of the city, newest first: published ones with their recommendation, failed ones with the
    reason (a failed solve keeps the previous recommendation current)."""
    served, records = fleet.recommendation_history(city, limit)
    hz = served.horizon
    entries = [
        FleetHistoryEntryOut.of(
            record,
            hz,
            recommendation=_recommendation(record, hz.timezone) if record.status == "published" else None,
        )
        for record in records
    ]
    return FleetHistoryOut(city=city, entries=entries)


@router.get(
    "/{city}/fleet/status",
    response_model=FleetStatusOut,
    summary="The fleet worker: heartbeat, solve in progress, last and next solve",
    responses=READ_ERRORS,
)
def get_status(city: CityName, _: ReadAccess, fleet: FleetDep) -> FleetStatusOut:
    """The workers serving the city by their last heartbeat (`worker.seen`: one was seen within
    `stale_after_s`, else `hint` says how to start one), the history a solve today is sized on (`history`:
    "collecting history: k of M days" and the first day a solve is possible), why the worker does not size
    the city now (`waiting`), the solve in progress with its simulation runs (`solving`: "k of n runs"),
    the pending request, the last solve (published or failed) and the next scheduled one."""
    return FleetStatusOut.of(fleet.status(city), START_WORKER_HINT)


@router.post(
    "/{city}/fleet/solve",
    status_code=202,
    response_model=SolveRequestOut,
    summary="Ask the worker for a solve now",
    responses=errors(401, 403, 404, 409, 422, 500, 503),
)
def post_solve(city: CityName, principal: AdminAccess, fleet: FleetDep) -> SolveRequestOut:
    """Queue a solve of the coming hour for the worker, which polls its queue every few seconds (202 with the
    request id; the solve shows up in the history with that id, GET .../fleet/status shows its progress). A
    request already pending is not duplicated: this one joins it (`already_queued`, same id). A city that
    does not have the M days of history it is sized on yet is refused with 409 `insufficient_history`
    (`history`: the days it has, the days it needs, the first day a solve is possible); when no worker
    serving the city has been seen recently the request is refused with 503 `no_worker` (saying how to start
    one). A refused request queues nothing."""
    served, result = fleet.request_solve(city, uuid.uuid4().hex, principal.name)
    tz = served.horizon.timezone
    return SolveRequestOut(
        request_id=result.request.request_id,
        city=city,
        status="queued" if result.created else "already_queued",
        requested_at=format_time(result.request.requested_at_s, tz),
    )
