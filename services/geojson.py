"""GeoJSON (RFC 7946) views of a city for GIS tools and the dashboard: the road network, the sensing grid with
its counts, and the routes and tasks of one decision epoch.

Every function returns a JSON-ready ``FeatureCollection`` dict. Positions are WGS84 ``[lon, lat]`` rounded to
``DECIMALS`` places (about 0.1 m); polygon rings are closed and counterclockwise (RFC 7946 section 3.1.6).
Grid cells are squares in the city's projected plane (``services.sensing.grid``); their corners are projected
back to WGS84 once per grid line crossing, so neighbouring cells share their corner positions exactly.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from services.model import RiderMatch, Task, TaskAssignment
from services.network.network import Network, lonlat_of
from services.rfc3339 import format_time
from services.sensing.grid import Grid

__all__ = [
    "DECIMALS",
    "GeoJson",
    "network_geojson",
    "cell_rings",
    "grid_geojson",
    "routes_geojson",
]

DECIMALS = 6
"""Decimal places of a coordinate: 1e-6 degree is 0.11 m of latitude."""

GeoJson = dict[str, Any]
"""A GeoJSON object as a JSON-ready dict."""


def _collection(features: list[GeoJson], bbox: Sequence[float] | None = None) -> GeoJson:
    doc: GeoJson = {"type": "FeatureCollection", "features": features}
    if bbox is not None:
        doc["bbox"] = [float(v) for v in bbox]
    return doc


def _feature(geometry: GeoJson, properties: dict[str, Any], fid: int | str | None = None) -> GeoJson:
    doc: GeoJson = {"type": "Feature", "geometry": geometry, "properties": properties}
    if fid is not None:
        doc["id"] = fid
    return doc


def _positions(network: Network, nodes: Sequence[int] | NDArray[np.int64]) -> list[list[float]]:
    idx = np.asarray(nodes, dtype=np.int64)
    lon = np.round(network.lon[idx], DECIMALS).tolist()
    lat = np.round(network.lat[idx], DECIMALS).tolist()
    return [[x, y] for x, y in zip(lon, lat, strict=True)]


def _bbox_of(network: Network) -> list[float]:
    """[west, south, east, north] of the network's nodes, widened to the rounding grid."""
    q = 10.0**DECIMALS
    return [
        float(np.floor(network.lon.min() * q) / q),
        float(np.floor(network.lat.min() * q) / q),
        float(np.ceil(network.lon.max() * q) / q),
        float(np.ceil(network.lat.max() * q) / q),
    ]


def network_geojson(network: Network) -> GeoJson:
    """The road network: one LineString per directed edge, tail to head.

    Parameters
    ----------
    network : Network

    Returns
    -------
    dict
        A FeatureCollection with a ``bbox``; feature ``i`` is edge ``i`` (``id`` = edge index) with properties
        ``id``, ``u`` and ``v`` (external node ids of tail and head), ``length_m`` and ``travel_time_s``. A
        two-way street is two features with opposite directions.
    """
    lon = np.round(network.lon, DECIMALS).tolist()
    lat = np.round(network.lat, DECIMALS).tolist()
    ids = network.node_ids.tolist()
    features = [
        _feature(
            {"type": "LineString", "coordinates": [[lon[u], lat[u]], [lon[v], lat[v]]]},
            {"id": e, "u": ids[u], "v": ids[v], "length_m": length, "travel_time_s": t},
            e,
        )
        for e, (u, v, length, t) in enumerate(
            zip(
                network.edge_u.tolist(),
                network.edge_v.tolist(),
                network.edge_length_m.tolist(),
                network.edge_time_s.tolist(),
                strict=True,
            )
        )
    ]
    return _collection(features, _bbox_of(network) if network.n_nodes else None)


def cell_rings(grid: Grid) -> NDArray[np.float64]:
    """The exterior ring of every grid cell in WGS84.

    Parameters
    ----------
    grid : Grid

    Returns
    -------
    float64 (n_cells, 5, 2)
        Ring of cell ``row * n_cols + col``: its projected corners (x0, y0), (x1, y0), (x1, y1), (x0, y1) and
        (x0, y0) again, counterclockwise, as [lon, lat] rounded to ``DECIMALS``. A corner shared by several
        cells has the same position in each.
    """
    xs = grid.origin_x_m + grid.cell_m * np.arange(grid.n_cols + 1, dtype=np.float64)
    ys = grid.origin_y_m + grid.cell_m * np.arange(grid.n_rows + 1, dtype=np.float64)
    gx, gy = np.meshgrid(xs, ys)  # lattice point (i, j) is row line i, column line j
    lon, lat = lonlat_of(grid.crs, gx, gy)
    corners = np.round(np.stack([lon, lat], axis=-1), DECIMALS)  # (n_rows + 1, n_cols + 1, 2)
    row, col = np.divmod(np.arange(grid.n_cells), grid.n_cols)
    ring_rows = row[:, None] + np.array([0, 0, 1, 1, 0])
    ring_cols = col[:, None] + np.array([0, 1, 1, 0, 0])
    rings: NDArray[np.float64] = corners[ring_rows, ring_cols]
    return rings


def grid_geojson(grid: Grid, counts: NDArray[np.int64], cell_weight: NDArray[np.float64]) -> GeoJson:
    """One Polygon per cell of the grid with its count Lambda of one sensing interval.

    Parameters
    ----------
    grid : Grid
    counts : int (n_cells,)
        Lambda of every cell (distinct instrumented vehicles that crossed it in the interval).
    cell_weight : float (n_cells,)
        s_g of every cell (positive exactly on the cells the network touches, Eq. (2)).

    Returns
    -------
    dict
        A FeatureCollection with a ``bbox``; feature ``c`` is cell ``c`` (``id`` = cell index) with
        properties ``cell``, ``col``, ``row``, ``lambda``, ``sensed`` (Lambda > 0) and ``weight`` (s_g).
    """
    lam = np.asarray(counts)
    weight = np.asarray(cell_weight, dtype=np.float64)
    if lam.shape != (grid.n_cells,) or weight.shape != (grid.n_cells,):
        raise ValueError(f"counts and cell_weight must have one entry per cell ({grid.n_cells})")
    if lam.size and (not np.issubdtype(lam.dtype, np.integer) or lam.min() < 0):
        raise ValueError("counts must be non-negative integers")
    rings = cell_rings(grid)
    features = []
    for c, (ring, n, w) in enumerate(zip(rings.tolist(), lam.tolist(), weight.tolist(), strict=True)):
        col, row = grid.col_row(c)
        features.append(
            _feature(
                {"type": "Polygon", "coordinates": [ring]},
                {"cell": c, "col": col, "row": row, "lambda": n, "sensed": n > 0, "weight": w},
                c,
            )
        )
    bbox = None
    if rings.size:
        lo = rings.reshape(-1, 2).min(axis=0)
        hi = rings.reshape(-1, 2).max(axis=0)
        bbox = [lo[0], lo[1], hi[0], hi[1]]
    return _collection(features, bbox)


def _num(value: float) -> float | None:
    """A float for JSON: ``None`` in place of NaN or infinity, which JSON cannot write."""
    v = float(value)
    return v if np.isfinite(v) else None


def _local_time(time_s: float, timezone: str) -> str | None:
    """RFC 3339 text in ``timezone``; ``None`` for a time that is not known (not finite)."""
    return format_time(time_s, timezone) if np.isfinite(time_s) else None


def _path_geometry(network: Network, path: Sequence[int]) -> GeoJson:
    """A LineString along the path's nodes; a path of one node (the taxi is already there) is a Point."""
    if len(path) == 0:
        raise ValueError("a route has at least one node")
    if len(path) == 1:
        return {"type": "Point", "coordinates": _positions(network, path)[0]}
    return {"type": "LineString", "coordinates": _positions(network, path)}


def _rider_feature(network: Network, m: RiderMatch, time_s: float, timezone: str) -> GeoJson:
    """A Step 1 or 2 match: the taxi's path to the pickup and on to the dropoff, departing at ``time_s``."""
    props: dict[str, Any] = {
        "kind": "rider",
        "step": int(m.step),
        "taxi_id": str(m.taxi_id),
        "rider_id": str(m.rider_id),
        "sensing_gain": _num(m.sensing_gain),
        "pickup_m": _num(m.pickup_m),
        "wait_s": _num(m.wait_s),
        "trip_m": _num(m.trip_m),
        "trip_time_s": _num(m.trip_time_s),
        "depart_at": _local_time(time_s, timezone),
        "pickup_at": _local_time(time_s + m.wait_s, timezone),
        "dropoff_at": _local_time(time_s + (m.wait_s + m.trip_time_s), timezone),
    }
    return _feature(_path_geometry(network, m.path), props)


def _poi_feature(network: Network, a: TaskAssignment, time_s: float, timezone: str) -> GeoJson:
    """A Step 3 assignment: the instrumented taxi's route to its POI, departing at ``time_s``."""
    props: dict[str, Any] = {
        "kind": "poi",
        "step": 3,
        "taxi_id": str(a.taxi_id),
        "task_id": str(a.task_id),
        "sensing_gain": _num(a.sensing_gain),
        "efficiency": _num(a.efficiency),
        "length_m": _num(a.length_m),
        "travel_time_s": _num(a.travel_time_s),
        "cost_cny": _num(a.cost_cny),
        "depart_at": _local_time(time_s, timezone),
        "arrive_at": _local_time(time_s + a.travel_time_s, timezone),
    }
    return _feature(_path_geometry(network, a.path), props)


def _task_feature(network: Network, t: Task, timezone: str) -> GeoJson:
    """A task as a Point at its POI node, with its status."""
    props: dict[str, Any] = {
        "kind": "task",
        "task_id": str(t.id),
        "node": int(network.node_ids[t.node]),
        "status": t.status,
        "scheduled_at": _local_time(t.scheduled_at_s, timezone),
        "completed_at": None if t.completed_at_s is None else _local_time(t.completed_at_s, timezone),
        "taxi_id": None if t.taxi_id is None else str(t.taxi_id),
        "mode": t.mode,
    }
    return _feature(_path_geometry(network, [t.node]), props)


def routes_geojson(
    network: Network,
    time_s: float,
    timezone: str,
    rider_matches: Sequence[RiderMatch],
    task_assignments: Sequence[TaskAssignment],
    tasks: Sequence[Task],
) -> GeoJson:
    """The paths of one decision epoch and the tasks it concerns.

    Parameters
    ----------
    network : Network
    time_s : float
        The epoch's time (every planned path departs then).
    timezone : str
        IANA zone the times are written in (the city's).
    rider_matches : RiderMatch sequence
        Steps 1 and 2: each taxi's path to the pickup and on to the dropoff.
    task_assignments : TaskAssignment sequence
        Step 3: each vacant instrumented taxi's route to its POI (Algorithm 2).
    tasks : Task sequence
        Tasks to show as Points at their POI node, with their status.

    Returns
    -------
    dict
        A FeatureCollection of, in this order:

        * rider paths (``kind`` "rider"): ``step`` (1 or 2), ``taxi_id``, ``rider_id``, ``sensing_gain``,
          ``pickup_m``, ``wait_s``, ``trip_m``, ``trip_time_s``, ``depart_at``, ``pickup_at``,
          ``dropoff_at``;
        * POI routes (``kind`` "poi", ``step`` 3): ``taxi_id``, ``task_id``, ``sensing_gain``,
          ``efficiency`` (Eq. (12)), ``length_m``, ``travel_time_s``, ``cost_cny``,
          ``depart_at``, ``arrive_at``;
        * tasks (``kind`` "task", Points): ``task_id``, ``node`` (external id), ``status``,
          ``scheduled_at``, ``completed_at``, ``taxi_id``, ``mode``.

        Paths are LineStrings through their nodes (a one-node path is a Point); times are RFC 3339 in
        ``timezone``; a number or time that is not finite (not known) is written as null.
    """

    features = [_rider_feature(network, m, time_s, timezone) for m in rider_matches]
    features += [_poi_feature(network, a, time_s, timezone) for a in task_assignments]
    features += [_task_feature(network, t, timezone) for t in tasks]
    return _collection(features)
