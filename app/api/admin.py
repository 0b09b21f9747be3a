"""Admin routes (scope `admin`): rewind or reset a city's epoch stream, with the city's name repeated in the
body as confirmation. When and how: the README ("Rewind or reset") and docs/DESIGN.md."""

from __future__ import annotations

from fastapi import APIRouter

from app.api.bodies import ResetBody, RewindBody, request_body
from app.api.deps import AdminAccess, AdminDep, CityName
from app.api.responses import errors
from app.errors import InvalidInput
from app.schemas.admin import EpochStreamOut, ResetIn, RewindIn
from app.usecases import StreamChange
from services.rfc3339 import format_time

__all__ = ["router"]

router = APIRouter(
    prefix="/v1/cities", tags=["admin"], responses=errors(400, 401, 403, 404, 413, 415, 422, 500, 503)
)


def _confirmed(city: str, confirm: str) -> None:
    if confirm != city:
        raise InvalidInput.at("confirm", f"must repeat the city's name {city!r} to confirm")


def _out(change: StreamChange) -> EpochStreamOut:
    tz = change.city.horizon.timezone
    return EpochStreamOut(
        city=change.city.name,
        action="rewind" if change.action == "rewind" else "reset",
        previous_last_epoch_time=None
        if change.previous_time_s is None
        else format_time(change.previous_time_s, tz),
        last_epoch_time=None if change.time_s is None else format_time(change.time_s, tz),
        committed=change.committed,
        deleted_keys=change.deleted,
    )


@router.post(
    "/{city}/admin/rewind",
    response_model=EpochStreamOut,
    summary="Rewind a city's epoch stream",
    openapi_extra=request_body(RewindIn),
)
def post_rewind(city: CityName, body: RewindBody, _: AdminAccess, admin: AdminDep) -> EpochStreamOut:
    """Move the city's last epoch time back to `to`, so that epochs at `to` or later are accepted again
    (after an epoch dated far ahead made every later one `stale_epoch`). What committed epochs wrote (counts,
    tasks, epoch records) stays; epoch ids stay used. 404 `no_data` when no epoch was committed; 422 when
    `to` is later than the last epoch time or `confirm` is not the city's name."""
    _confirmed(city, body.confirm)
    return _out(admin.rewind(city, body.to.timestamp()))


@router.post(
    "/{city}/admin/reset",
    response_model=EpochStreamOut,
    summary="Reset a city's epoch stream",
    openapi_extra=request_body(ResetIn),
)
def post_reset(city: CityName, body: ResetBody, _: AdminAccess, admin: AdminDep) -> EpochStreamOut:
    """Delete the city's epoch stream: committed epoch records, grid counts and visits, recorded demand, the
    epoch count and last time, and its tasks. Fleet-sizing recommendations stay. Stop posting the city's
    epochs first: a commit racing the reset may leave part of itself behind. 422 when `confirm` is not the
    city's name."""
    _confirmed(city, body.confirm)
    return _out(admin.reset(city))
