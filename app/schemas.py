"""Request and response models of the HTTP API, and their conversion from the core's dataclasses."""

from __future__ import annotations

import datetime as dt
import re
from typing import Annotated, Any, Literal
from zoneinfo import ZoneInfo

import numpy as np
from pydantic import (
    AwareDatetime,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    StrictBool,
    StrictInt,
    StringConstraints,
    field_validator,
    model_validator,
)

from services.city import City
from services.model import RiderMatch, Task, TaskAssignment

__all__ = [
    "ID_MAX_LEN",
    "Identifier",
    "Rfc3339",
    "parse_rfc3339",
    "LocationIn",
    "RiderIn",
    "TaxiIn",
    "EpochIn",
    "TaskIn",
    "FieldErrorOut",
    "ErrorOut",
    "HealthOut",
    "ReadyOut",
    "NetworkSizeOut",
    "GridOut",
    "HorizonOut",
    "ParamsOut",
    "CityOut",
    "CitiesOut",
    "GraphNodeOut",
    "GraphEdgeOut",
    "GraphOut",
    "TaskOut",
    "TasksOut",
    "TasksPutOut",
    "RiderMatchOut",
    "TaskAssignmentOut",
    "EpochOut",
    "CellCountOut",
    "CoverageOut",
    "format_time",
]

ID_MAX_LEN = 128
MIN_YEAR, MAX_YEAR = 1970, 2999
_RFC3339 = re.compile(r"^\d{4}-\d{2}-\d{2}[Tt ]\d{2}:\d{2}:\d{2}(\.\d{1,9})?([Zz]|[+-]\d{2}:\d{2})$")


class _In(BaseModel):
    """Base of request models: unknown fields are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class _Out(BaseModel):
    """Base of response models."""

    model_config = ConfigDict(extra="forbid")


def _check_rfc3339(value: Any) -> Any:
    """Accept only RFC 3339 text with seconds and an explicit offset (no numbers, no naive times)."""
    if not isinstance(value, str):
        raise ValueError(
            "must be an RFC 3339 date-time string with an offset, e.g. 2024-05-06T08:00:00+08:00"
        )
    if len(value) > 40 or not _RFC3339.match(value):
        raise ValueError(
            "must be an RFC 3339 date-time with seconds and an offset, e.g. 2024-05-06T08:00:00+08:00"
        )
    return value


def _check_year(value: dt.datetime) -> dt.datetime:
    if not MIN_YEAR <= value.astimezone(dt.UTC).year <= MAX_YEAR:
        raise ValueError(f"year must lie in {MIN_YEAR}..{MAX_YEAR}")
    return value


Rfc3339 = Annotated[AwareDatetime, BeforeValidator(_check_rfc3339)]
"""An RFC 3339 date-time with an explicit offset."""

Identifier = Annotated[
    str, StringConstraints(min_length=1, max_length=ID_MAX_LEN, pattern=r"^[^\x00-\x1f\x7f]+$")
]
NodeId = Annotated[StrictInt, Field(ge=-(2**63), le=2**63 - 1, description="External node id.")]
Lon = Annotated[float, Strict(), Field(ge=-180.0, le=180.0, allow_inf_nan=False)]
Lat = Annotated[float, Strict(), Field(ge=-90.0, le=90.0, allow_inf_nan=False)]


def parse_rfc3339(text: str) -> dt.datetime:
    """Parse RFC 3339 text with the same rules as request bodies (raises ``ValueError``)."""
    _check_rfc3339(text)
    value = dt.datetime.fromisoformat(text.replace("z", "Z"))
    if value.tzinfo is None:
        raise ValueError("missing offset")
    return _check_year(value)


class LocationIn(_In):
    """A position: ``{"node": id}`` or ``{"lon": x, "lat": y}`` (snapped to the nearest node)."""

    model_config = ConfigDict(
        extra="forbid",
        frozen=True,
        json_schema_extra={"oneOf": [{"required": ["node"]}, {"required": ["lon", "lat"]}]},
    )

    node: NodeId | None = None
    lon: Lon | None = Field(default=None, description="WGS84 longitude, degrees.")
    lat: Lat | None = Field(default=None, description="WGS84 latitude, degrees.")

    @model_validator(mode="after")
    def _one_form(self) -> LocationIn:
        if self.node is not None and (self.lon is not None or self.lat is not None):
            raise ValueError("give either node or lon and lat, not both")
        if self.node is None and (self.lon is None or self.lat is None):
            raise ValueError("give node, or both lon and lat")
        return self


class _Timed(_In):
    """Validates the year range of every RFC 3339 field."""

    @field_validator("*", mode="after")
    @classmethod
    def _year_range(cls, value: Any) -> Any:
        return _check_year(value) if isinstance(value, dt.datetime) else value


class RiderIn(_Timed):
    """A waiting rider."""

    id: Identifier
    origin: LocationIn
    destination: LocationIn
    requested_at: Rfc3339


class TaxiIn(_In):
    """A taxi's position and state at the epoch."""

    id: Identifier
    location: LocationIn
    instrumented: StrictBool
    status: Literal["vacant", "busy"]


class EpochIn(_Timed):
    """One decision epoch posted by the platform."""

    epoch_id: Identifier
    time: Rfc3339
    riders: list[RiderIn]
    taxis: list[TaxiIn]


class TaskIn(_Timed):
    """A monitoring task: a POI and the time from which it is open."""

    id: Identifier
    location: LocationIn
    scheduled_at: Rfc3339


# ----------------------------------------------------------------------------------------- responses


class FieldErrorOut(_Out):
    """One offending field."""

    loc: str = Field(description="Dotted location, e.g. riders[2].origin.lon.")
    msg: str


class ErrorOut(_Out):
    """The one error shape of the API."""

    error: str = Field(description="Machine-readable kind, e.g. validation_error, epoch_conflict.")
    detail: str
    fields: list[FieldErrorOut]


class HealthOut(_Out):
    """Liveness."""

    status: Literal["ok"]


class ReadyOut(_Out):
    """Readiness: store reachable and cities loaded."""

    status: Literal["ready"]
    store: str
    cities: list[str]


class NetworkSizeOut(_Out):
    """Size of a road network."""

    nodes: int
    edges: int
    road_km: float = Field(description="Total length of the directed edges, km.")


class GridOut(_Out):
    """The sensing grid."""

    crs: str
    origin: tuple[float, float] = Field(description="Lower-left corner [x_m, y_m] in crs.")
    cell_m: float
    n_cols: int
    n_rows: int
    n_cells_touched: int = Field(description="Cells the network touches (the coverage denominator).")


class HorizonOut(_Out):
    """The operating horizon."""

    timezone: str
    start: str = Field(description="Local start time, HH:MM:SS.")
    interval_s: int
    n_intervals: int
    epoch_s: int


class ParamsOut(_Out):
    """Dispatch parameters (services.city.DispatchParams)."""

    rho: float
    radius_m: float
    speed_kmh: float
    kappas: list[float]
    max_iter: int
    patience_s: float
    snap_limit_m: float
    unit_cost_cny_per_km: float
    subsidy_cny_per_vehicle_hour: float
    active_sensing: bool


class CityOut(_Out):
    """A served city."""

    name: str
    network: NetworkSizeOut
    bbox: tuple[float, float, float, float] = Field(description="[min_lon, min_lat, max_lon, max_lat].")
    grid: GridOut
    horizon: HorizonOut
    params: ParamsOut
    source: str = Field(description="Provenance and attribution.")

    @classmethod
    def of(cls, city: City) -> CityOut:
        """Describe ``city``."""
        net, grid, hz, p = city.network, city.grid, city.horizon, city.params
        bbox = (
            (float(net.lon.min()), float(net.lat.min()), float(net.lon.max()), float(net.lat.max()))
            if net.n_nodes
            else (0.0, 0.0, 0.0, 0.0)
        )
        return cls(
            name=city.name,
            network=NetworkSizeOut(
                nodes=net.n_nodes,
                edges=net.n_edges,
                road_km=round(float(net.edge_length_m.sum()) / 1000.0, 3),
            ),
            bbox=bbox,
            grid=GridOut(
                crs=grid.crs,
                origin=(float(grid.origin_x_m), float(grid.origin_y_m)),
                cell_m=float(grid.cell_m),
                n_cols=grid.n_cols,
                n_rows=grid.n_rows,
                n_cells_touched=int(np.count_nonzero(city.cell_weight > 0)),
            ),
            horizon=HorizonOut(
                timezone=hz.timezone,
                start=hz.start.isoformat(),
                interval_s=hz.interval_s,
                n_intervals=hz.n_intervals,
                epoch_s=hz.epoch_s,
            ),
            params=ParamsOut(
                rho=p.rho,
                radius_m=p.radius_m,
                speed_kmh=p.speed_kmh,
                kappas=list(p.kappas),
                max_iter=p.max_iter,
                patience_s=p.patience_s,
                snap_limit_m=p.snap_limit_m,
                unit_cost_cny_per_km=p.unit_cost_cny_per_km,
                subsidy_cny_per_vehicle_hour=p.subsidy_cny_per_vehicle_hour,
                active_sensing=p.active_sensing,
            ),
            source=city.source,
        )


class CitiesOut(_Out):
    """Every served city."""

    cities: list[CityOut]


class GraphNodeOut(_Out):
    """A network node with its grid cell."""

    id: int
    lon: float
    lat: float
    cell: tuple[int, int] = Field(description="[col, row] of the node's grid cell.")


class GraphEdgeOut(_Out):
    """A directed edge between external node ids."""

    u: int
    v: int
    length_m: float
    travel_time_s: float


class GraphOut(_Out):
    """The road network of a city."""

    nodes: list[GraphNodeOut]
    edges: list[GraphEdgeOut]


def format_time(time_s: float, tz: str) -> str:
    """RFC 3339 text of POSIX time ``time_s`` in the city's time zone."""
    return dt.datetime.fromtimestamp(time_s, tz=ZoneInfo(tz)).isoformat()


class TaskOut(_Out):
    """A monitoring task and its lifecycle."""

    id: str
    node: int = Field(description="External id of the POI node.")
    status: Literal["pending", "assigned", "completed"]
    scheduled_at: str
    completed_at: str | None = Field(description="When the POI is (or will be, if assigned) reached.")
    taxi_id: str | None
    mode: Literal["passive", "active"] | None

    @classmethod
    def of(cls, city: City, task: Task) -> TaskOut:
        """Render a core task with external node ids and local times."""
        tz = city.horizon.timezone
        return cls(
            id=str(task.id),
            node=int(city.network.node_ids[task.node]),
            status=task.status,
            scheduled_at=format_time(task.scheduled_at_s, tz),
            completed_at=None if task.completed_at_s is None else format_time(task.completed_at_s, tz),
            taxi_id=None if task.taxi_id is None else str(task.taxi_id),
            mode=task.mode,
        )


class TasksOut(_Out):
    """All tasks of a city."""

    tasks: list[TaskOut]


class TasksPutOut(_Out):
    """Outcome of registering tasks (idempotent per id)."""

    created: list[str]
    unchanged: list[str]


def _ext_path(city: City, path: tuple[int, ...]) -> list[int]:
    return [int(v) for v in city.network.node_ids[list(path)]] if path else []


def _cells(cells: tuple[tuple[int, int], ...]) -> list[tuple[int, int]]:
    return [(int(c), int(r)) for c, r in cells]


class RiderMatchOut(_Out):
    """A taxi sent to a rider (Step 1: instrumented, Step 2: not)."""

    step: Literal[1, 2]
    taxi_id: str
    rider_id: str
    pickup_m: float
    wait_s: float
    trip_m: float
    sensing_gain: float
    path: list[int] = Field(description="External node ids from the taxi via the pickup to the dropoff.")
    cells: list[tuple[int, int]] = Field(description="G-route of the path, [col, row] in order.")

    @classmethod
    def of(cls, city: City, m: RiderMatch) -> RiderMatchOut:
        """Render a core match."""
        return cls(
            step=m.step,
            taxi_id=str(m.taxi_id),
            rider_id=str(m.rider_id),
            pickup_m=float(m.pickup_m),
            wait_s=float(m.wait_s),
            trip_m=float(m.trip_m),
            sensing_gain=float(m.sensing_gain),
            path=_ext_path(city, m.path),
            cells=_cells(m.cells),
        )


class TaskAssignmentOut(_Out):
    """A vacant instrumented taxi sent along a sensing route to a POI (Step 3)."""

    taxi_id: str
    task_id: str
    path: list[int]
    cells: list[tuple[int, int]]
    length_m: float
    travel_time_s: float
    sensing_gain: float
    efficiency: float = Field(description="sensing_gain / travel_time_s (Eq. 12).")
    cost_cny: float

    @classmethod
    def of(cls, city: City, a: TaskAssignment) -> TaskAssignmentOut:
        """Render a core assignment."""
        return cls(
            taxi_id=str(a.taxi_id),
            task_id=str(a.task_id),
            path=_ext_path(city, a.path),
            cells=_cells(a.cells),
            length_m=float(a.length_m),
            travel_time_s=float(a.travel_time_s),
            sensing_gain=float(a.sensing_gain),
            efficiency=float(a.efficiency),
            cost_cny=float(a.cost_cny),
        )


class EpochOut(_Out):
    """What was decided for one epoch."""

    epoch_id: str
    time: str
    rider_matches: list[RiderMatchOut]
    task_assignments: list[TaskAssignmentOut]
    tasks_completed: list[TaskOut]
    unmatched_rider_ids: list[str]
    expired_rider_ids: list[str]
    stats: dict[str, float | int | str] = Field(
        description="Matches per step, interval label, solve time, Gamma and other diagnostics."
    )


class CellCountOut(_Out):
    """Lambda of one cell."""

    cell: tuple[int, int]
    count: int


class CoverageOut(_Out):
    """Grid counts of one sensing interval."""

    city: str
    interval: str = Field(description="Local start of the interval, YYYY-MM-DDTHH:MM.")
    interval_key: int
    in_horizon: bool
    cells: list[CellCountOut] = Field(description="Cells with a non-zero count.")
    coverage_rate: float = Field(description="Share of the network's cells with Lambda >= 1.")
    gamma_so_far: float = Field(description="Gamma over that day's horizon intervals, as counted so far.")
    n_cells_covered: int
    n_cells_touched: int
