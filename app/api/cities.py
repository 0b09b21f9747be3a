"""Read routes: cities, their road graph, tasks and grid coverage, the graph and coverage also as GeoJSON
(scope `read`)."""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated

from fastapi import APIRouter, Query, Request, Response

from app.api.deps import CitiesDep, CityName, CoverageDep, ReadAccess, TasksDep
from app.api.geojson import Packed, dump, geojson_responses, pack, respond
from app.api.inputs import INTERVAL_PATTERN, interval_of
from app.api.responses import READ_ERRORS
from app.schemas.cities import CitiesOut, CityOut, GraphOut
from app.schemas.coverage import CoverageOut
from app.schemas.tasks import TaskOut, TasksOut
from services.city import City
from services.geojson import grid_geojson, network_geojson

__all__ = ["router"]

router = APIRouter(prefix="/v1/cities", tags=["cities"], responses=READ_ERRORS)


@router.get("", response_model=CitiesOut, summary="Served cities")
def list_cities(_: ReadAccess, catalog: CitiesDep) -> CitiesOut:
    """Every served city with its network size, grid, horizon and parameters."""
    return CitiesOut(cities=[CityOut.of(catalog.get(name)) for name in catalog.names()])


@router.get("/{city}", response_model=CityOut, summary="One city")
def get_city(city: CityName, _: ReadAccess, catalog: CitiesDep) -> CityOut:
    """A city's network size, bbox, grid, horizon, dispatch parameters and source."""
    return CityOut.of(catalog.get(city))


@router.get("/{city}/graph", response_model=GraphOut, summary="Road network")
def get_graph(city: CityName, _: ReadAccess, catalog: CitiesDep) -> Response:
    """Nodes (external id, lon/lat, grid cell) and directed edges (external ids, length, time)."""
    return Response(content=_graph_json(catalog.get(city)), media_type="application/json")


@lru_cache(maxsize=8)
def _graph_json(city: City) -> bytes:
    """The graph document of a city, rendered once (a city is immutable and hashed by identity)."""
    return GraphOut.of(city).model_dump_json().encode()


@router.get(
    "/{city}/graph.geojson",
    summary="Road network as GeoJSON",
    response_class=Response,
    responses=geojson_responses(
        "One LineString per directed edge, tail to head (`id` = edge index), with properties `id`, `u`, `v` "
        "(external node ids), `length_m` and `travel_time_s`; gzipped when the client accepts it."
    ),
)
def get_graph_geojson(city: CityName, _: ReadAccess, catalog: CitiesDep, request: Request) -> Response:
    """The road network for GIS tools (QGIS, kepler.gl, geopandas) and the dashboard's base map."""
    return respond(request, _graph_geojson(catalog.get(city)))


@lru_cache(maxsize=8)
def _graph_geojson(city: City) -> Packed:
    """The network's GeoJSON, rendered and compressed once (3 MB of text for Chengdu, 0.4 MB gzipped)."""
    return pack(network_geojson(city.network))


@router.get("/{city}/tasks", response_model=TasksOut, summary="Monitoring tasks")
def list_tasks(city: CityName, _: ReadAccess, registered: TasksDep) -> TasksOut:
    """Every task of the city with its status, completion time, taxi and mode."""
    served, tasks = registered.list_tasks(city)
    return TasksOut(tasks=[TaskOut.of(served, t) for t in tasks])


@router.get("/{city}/coverage", response_model=CoverageOut, summary="Grid counts of one interval")
def get_coverage(
    city: CityName,
    _: ReadAccess,
    catalog: CitiesDep,
    coverage: CoverageDep,
    interval: Annotated[
        str | None,
        Query(
            max_length=40,
            pattern=INTERVAL_PATTERN,
            description="Interval label YYYY-MM-DDTHH:MM (local start) or any RFC 3339 time inside it; "
            "default: the interval of the last committed epoch.",
        ),
    ] = None,
) -> CoverageOut:
    """Lambda per covered cell, coverage rate and Gamma so far for one sensing interval."""
    k = None if interval is None else interval_of(catalog.get(city), interval)
    return CoverageOut.of(coverage.coverage(city, k))


@router.get(
    "/{city}/coverage.geojson",
    summary="Grid counts of one interval as GeoJSON",
    response_class=Response,
    responses=geojson_responses(
        "One Polygon per cell of the city's grid (`id` = cell index; the counterclockwise WGS84 ring of the "
        "projected square) with properties `cell`, `col`, `row`, `lambda` (distinct instrumented vehicles "
        "that crossed it in the interval), `sensed` (lambda > 0) and `weight` (s_g); members `city`, "
        "`interval` and `interval_key`."
    ),
)
def get_coverage_geojson(
    city: CityName,
    _: ReadAccess,
    catalog: CitiesDep,
    coverage: CoverageDep,
    request: Request,
    interval: Annotated[
        str,
        Query(
            max_length=40,
            pattern=INTERVAL_PATTERN,
            description="Interval label YYYY-MM-DDTHH:MM (local start) or any RFC 3339 time inside it.",
        ),
    ],
) -> Response:
    """Lambda of every grid cell in one sensing interval: the cells of `GET .../coverage` as polygons."""
    cov = coverage.coverage(city, interval_of(catalog.get(city), interval))
    doc = grid_geojson(cov.city.grid, cov.counts, cov.city.cell_weight)
    doc.update({"city": cov.city.name, "interval": cov.city.horizon.label(cov.interval)})
    doc["interval_key"] = int(cov.interval)
    return respond(request, dump(doc))
