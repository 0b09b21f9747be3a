"""Read routes of committed epochs (scope `read`): the epoch log, a stored decision, and its routes as
GeoJSON. An epoch id may hold a slash (send it as `%2F`); the `routes.geojson` route is matched first."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Request, Response

from app.api.deps import CityName, EpochsDep, ReadAccess
from app.api.geojson import dump, geojson_responses, respond
from app.api.responses import READ_ERRORS
from app.schemas.common import ID_MAX_LEN
from app.schemas.decision import EpochOut
from app.schemas.epochs import EpochLogOut
from services.geojson import routes_geojson
from services.rfc3339 import format_time

__all__ = ["router"]

router = APIRouter(prefix="/v1/cities", tags=["epochs"], responses=READ_ERRORS)

EpochId = Annotated[
    str, Path(min_length=1, max_length=ID_MAX_LEN, description="The epoch's id, as it was posted.")
]


@router.get("/{city}/epochs", response_model=EpochLogOut, summary="Committed epochs")
def get_epoch_log(city: CityName, _: ReadAccess, epochs: EpochsDep) -> EpochLogOut:
    """How many epochs the city has committed and the last one (its id names it in the routes below)."""
    return EpochLogOut.of(epochs.epoch_log(city))


@router.get(
    "/{city}/epochs/{epoch_id:path}/routes.geojson",
    summary="Routes of a committed epoch as GeoJSON",
    response_class=Response,
    responses=geojson_responses(
        "Rider paths (`kind` rider, `step` 1 or 2, `taxi_id`, `rider_id`, `sensing_gain`, `pickup_m`, "
        "`wait_s`, `trip_m`, `trip_time_s`, `depart_at`, `pickup_at`, `dropoff_at`), then POI routes "
        "(`kind` poi, `step` 3, `taxi_id`, `task_id`, `sensing_gain`, `efficiency`, `length_m`, "
        "`travel_time_s`, `cost_cny`, `depart_at`, `arrive_at`) as LineStrings through their nodes (a "
        "one-node path is a Point), then the tasks the epoch assigned or completed as Points (`kind` task, "
        "`task_id`, `node`, `status` as the epoch left it, `scheduled_at`, `completed_at`, `taxi_id`, "
        "`mode`); members `city`, `epoch_id` and `time`. Times are RFC 3339 in the city's zone."
    ),
)
def get_epoch_routes(
    city: CityName, epoch_id: EpochId, _: ReadAccess, epochs: EpochsDep, request: Request
) -> Response:
    """The paths one committed epoch planned, for GIS tools and the dashboard."""
    routes = epochs.epoch_routes(city, epoch_id)
    d, served = routes.decision, routes.city
    doc = routes_geojson(
        served.network, d.time_s, served.horizon.timezone, d.rider_matches, d.task_assignments, routes.tasks
    )
    doc.update({"city": served.name, "epoch_id": d.epoch_id})
    doc["time"] = format_time(d.time_s, served.horizon.timezone)
    return respond(request, dump(doc))


@router.get("/{city}/epochs/{epoch_id:path}", response_model=EpochOut, summary="A committed epoch's decision")
def get_epoch(city: CityName, epoch_id: EpochId, _: ReadAccess, epochs: EpochsDep) -> Response:
    """The stored response of a committed epoch, byte for byte what its post returned."""
    stored = epochs.stored_epoch(city, epoch_id)
    return Response(content=stored.response_json, media_type="application/json")
