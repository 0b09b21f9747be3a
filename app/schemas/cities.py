"""Models of the city routes (``app.api.cities``): served cities and their road graph."""

from __future__ import annotations

from pydantic import Field

from app.schemas.common import ResponseModel
from services.city import City
from services.routing.step3 import step3_reach
from services.sensing.grid import node_col_row

__all__ = [
    "NetworkSizeOut",
    "GridOut",
    "HorizonOut",
    "ParamsOut",
    "CityOut",
    "CitiesOut",
    "GraphNodeOut",
    "GraphEdgeOut",
    "GraphOut",
]


class NetworkSizeOut(ResponseModel):
    """Size of a road network."""

    nodes: int
    edges: int
    road_km: float = Field(description="Total length of the directed edges, km.")


class GridOut(ResponseModel):
    """The sensing grid."""

    crs: str
    origin: tuple[float, float] = Field(description="Lower-left corner [x_m, y_m] in crs.")
    cell_m: float
    n_cols: int
    n_rows: int
    n_cells_touched: int = Field(description="Cells the network touches (the coverage denominator).")


class HorizonOut(ResponseModel):
    """The operating horizon."""

    timezone: str
    start: str = Field(description="Local start time, HH:MM:SS.")
    interval_s: int
    n_intervals: int
    epoch_s: int


class ParamsOut(ResponseModel):
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
    step3_reach_s: float | None = Field(
        description="Step 3's reach on this city: a POI considers the taxis whose fastest path to it takes "
        "at most this many seconds; null: every vacant instrumented taxi is a candidate for every POI "
        "(docs/METHOD.md section 4). It applies on networks that take longer than step3_reach_above_s to "
        "cross."
    )
    step3_reach_configured_s: float | None = Field(description="The city's configured reach (null: none).")
    step3_reach_above_s: float
    crossing_s: float = Field(
        description="How long the network takes to cross, at least: the longest fastest path to or from a "
        "landmark (a lower bound on its diameter in travel time)."
    )


class FleetParamsOut(ResponseModel):
    """The city's fleet-sizing parameters as its ``city.json`` sets them (docs/FLEET.md, "Per city"); null:
    not set, so each solve derives it from the fleet the platform posted (sizes, n0) or takes the worker's
    setting (days, subsidy, completion target)."""

    sizes: list[int] | None = Field(
        description="Candidate instrumented fleet sizes N1 (null: spread from a quarter to twice the "
        "instrumented fleet posted)."
    )
    n0: int | None = Field(
        description="Ordinary taxis in every simulated day (null: the ordinary fleet posted)."
    )
    days: int | None = Field(description="M, days of history per solve (null: SD_WORKER_DAYS).")
    subsidy_cny_per_vehicle_hour: float | None = Field(
        description="ζ (null: SD_WORKER_SUBSIDY_CNY_PER_VEHICLE_HOUR)."
    )
    completion_target: float | None = Field(
        description="Worst-case completion rate every choice must meet (null: SD_WORKER_COMPLETION_TARGET)."
    )
    synthetic_history: bool = Field(
        description="A demo city: sized on its demand generator's seeded days until M days are recorded "
        "(false: the city waits for its recorded history)."
    )


class CityOut(ResponseModel):
    """A served city."""

    name: str
    network: NetworkSizeOut
    bbox: tuple[float, float, float, float] = Field(description="[min_lon, min_lat, max_lon, max_lat].")
    grid: GridOut
    horizon: HorizonOut
    params: ParamsOut
    fleet: FleetParamsOut
    source: str = Field(description="Provenance and attribution.")

    @classmethod
    def of(cls, city: City) -> CityOut:
        """Describe ``city``."""
        net, grid, hz, p = city.network, city.grid, city.horizon, city.params
        reach, crossing = step3_reach(city)
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
                n_cells_touched=city.n_cells_touched,
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
                step3_reach_s=reach,
                step3_reach_configured_s=p.step3_reach_s,
                step3_reach_above_s=p.step3_reach_above_s,
                crossing_s=round(crossing, 3),
            ),
            fleet=FleetParamsOut(
                sizes=None if city.fleet.sizes is None else list(city.fleet.sizes),
                n0=city.fleet.n0,
                days=city.fleet.days,
                subsidy_cny_per_vehicle_hour=city.fleet.subsidy_cny_per_vehicle_hour,
                completion_target=city.fleet.completion_target,
                synthetic_history=city.fleet.synthetic_history,
            ),
            source=city.source,
        )


class CitiesOut(ResponseModel):
    """Every served city."""

    cities: list[CityOut]


class GraphNodeOut(ResponseModel):
    """A network node with its grid cell."""

    id: int
    lon: float
    lat: float
    cell: tuple[int, int] = Field(description="[col, row] of the node's grid cell.")


class GraphEdgeOut(ResponseModel):
    """A directed edge between external node ids."""

    u: int
    v: int
    length_m: float
    travel_time_s: float


class GraphOut(ResponseModel):
    """The road network of a city."""

    nodes: list[GraphNodeOut]
    edges: list[GraphEdgeOut]

    @classmethod
    def of(cls, city: City) -> GraphOut:
        """Nodes with external ids, lon/lat and grid cells; edges between external ids."""
        net = city.network
        col, row = node_col_row(city.grid, net)
        ids = net.node_ids
        return cls(
            nodes=[
                GraphNodeOut(id=int(i), lon=float(lo), lat=float(la), cell=(int(c), int(r)))
                for i, lo, la, c, r in zip(
                    ids.tolist(), net.lon.tolist(), net.lat.tolist(), col.tolist(), row.tolist(), strict=True
                )
            ],
            edges=[
                GraphEdgeOut(u=int(ids[u]), v=int(ids[v]), length_m=float(length), travel_time_s=float(t))
                for u, v, length, t in zip(
                    net.edge_u.tolist(),
                    net.edge_v.tolist(),
                    net.edge_length_m.tolist(),
                    net.edge_time_s.tolist(),
                    strict=True,
                )
            ],
        )
