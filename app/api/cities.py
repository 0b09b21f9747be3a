"""Read routes: cities, their road graph, tasks and grid coverage (scope `read`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response

from app.api.deps import CityName, ReadAccess, ServiceDep
from app.api.responses import READ_ERRORS
from app.schemas import CitiesOut, CityOut, CoverageOut, GraphOut, TasksOut

__all__ = ["router"]

router = APIRouter(prefix="/v1/cities", tags=["cities"], responses=READ_ERRORS)


@router.get("", response_model=CitiesOut, summary="Served cities")
def list_cities(_: ReadAccess, service: ServiceDep) -> CitiesOut:
    """Every served city with its network size, grid, horizon and parameters."""
    return CitiesOut(cities=[CityOut.of(service.city(name)) for name in service.city_names()])


@router.get("/{city}", response_model=CityOut, summary="One city")
def get_city(city: CityName, _: ReadAccess, service: ServiceDep) -> CityOut:
    """A city's network size, bbox, grid, horizon, dispatch parameters and source."""
    return CityOut.of(service.city(city))


@router.get("/{city}/graph", response_model=GraphOut, summary="Road network")
def get_graph(city: CityName, _: ReadAccess, service: ServiceDep) -> Response:
    """Nodes (external id, lon/lat, grid cell) and directed edges (external ids, length, time)."""
    return Response(content=service.graph_json(city), media_type="application/json")


@router.get("/{city}/tasks", response_model=TasksOut, summary="Monitoring tasks")
def list_tasks(city: CityName, _: ReadAccess, service: ServiceDep) -> TasksOut:
    """Every task of the city with its status, completion time, taxi and mode."""
    return TasksOut(tasks=service.list_tasks(city))


@router.get("/{city}/coverage", response_model=CoverageOut, summary="Grid counts of one interval")
def get_coverage(
    city: CityName,
    _: ReadAccess,
    service: ServiceDep,
    interval: Annotated[
        str | None,
        Query(
            max_length=40,
            description="Interval label YYYY-MM-DDTHH:MM (local start) or any RFC 3339 time inside it; "
            "default: the interval of the last committed epoch.",
        ),
    ] = None,
) -> CoverageOut:
    """Lambda per covered cell, coverage rate and Gamma so far for one sensing interval."""
    return service.coverage(city, interval)
