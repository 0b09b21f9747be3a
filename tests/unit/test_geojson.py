"""GeoJSON views of a city (services.geojson), checked against RFC 7946 (tests/rfc7946.py), the projection
(pyproj's forward transform and geodesic areas) and hand-made networks and decisions."""

from __future__ import annotations

import datetime as dt
import json
import tempfile
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod, Transformer

from app.adapters.city_registry import BUNDLED_DIR, CityRegistry
from services.city import City
from services.geojson import DECIMALS, cell_rings, grid_geojson, network_geojson, routes_geojson
from services.model import RiderId, RiderMatch, Task, TaskAssignment, TaskId, TaxiId
from services.network.network import Network, build_network, lonlat_of
from services.sensing.grid import Grid, build_grid, cells_of_points
from tests import rfc7946

ROUND_M = 0.15  # 1e-6 degree of rounding is at most 0.11 m on either axis at these latitudes
GEOD = Geod(ellps="WGS84")


@cache
def bundled(name: str) -> City:
    return CityRegistry(BUNDLED_DIR, Path(tempfile.mkdtemp(prefix="no-user-cities-"))).get(name)


def small_network() -> Network:
    """Four nodes about 1 km apart in Chengdu (UTM 48N), edges both ways on a path 1-2-3 and 3->4."""
    lon = [104.0600, 104.0705, 104.0705, 104.0810]
    lat = [30.6500, 30.6500, 30.6590, 30.6590]
    u = [1, 2, 2, 3, 3]
    v = [2, 1, 3, 2, 4]
    return build_network([1, 2, 3, 4], lon, lat, u, v, [1005.0, 1005.0, 998.0, 998.0, 1004.0])


# ------------------------------------------------------------------------------------------- checker


def test_the_checker_accepts_the_rfc_examples() -> None:
    point = {
        "type": "Feature",
        "geometry": {"type": "Point", "coordinates": [102.0, 0.5]},
        "properties": None,
    }
    poly = {
        "type": "Polygon",
        "coordinates": [
            [[100.0, 0.0], [101.0, 0.0], [101.0, 1.0], [100.0, 1.0], [100.0, 0.0]],
            [[100.8, 0.8], [100.8, 0.2], [100.2, 0.2], [100.2, 0.8], [100.8, 0.8]],
        ],
    }
    line = {"type": "LineString", "coordinates": [[102.0, 0.0], [103.0, 1.0], [104.0, 0.0]]}
    fc = {
        "type": "FeatureCollection",
        "bbox": [100.0, 0.0, 104.0, 1.0],
        "features": [point, {"type": "Feature", "geometry": poly, "properties": {"a": 1}, "id": 7}]
        + [{"type": "Feature", "geometry": line, "properties": {}}],
    }
    assert rfc7946.problems(fc) == []


@pytest.mark.parametrize(
    ("geometry", "complaint"),
    [
        ({"type": "Point", "coordinates": [30.6, 104.06, 1.0, 2.0]}, "array of 2"),
        ({"type": "Point", "coordinates": [30.6, 104.06]}, "not [lon, lat]"),  # lat, lon swapped
        ({"type": "LineString", "coordinates": [[104.0, 30.0]]}, "two or more"),
        ({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 1]]]}, "not closed"),
        ({"type": "Polygon", "coordinates": [[[0, 0], [0, 1], [1, 1], [1, 0], [0, 0]]]}, "counterclockwise"),
        ({"type": "Polygon", "coordinates": [[[0, 0], [1, 1], [1, 0], [0, 1], [0, 0]]]}, "counterclockwise"),
        ({"type": "Polygon", "coordinates": [[[0, 0], [2, 0], [0, 1], [2, 1], [0, 0]]]}, "not simple"),
        ({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [0, 0]]]}, "four or more"),
        ({"type": "Circle", "coordinates": [0, 0]}, "not a geometry"),
    ],
)
def test_the_checker_catches_violations(geometry: dict[str, object], complaint: str) -> None:
    found = rfc7946.problems({"type": "Feature", "geometry": geometry, "properties": {}})
    assert any(complaint in p for p in found), found


def test_the_checker_catches_bad_collections() -> None:
    line = {"type": "LineString", "coordinates": [[1.0, 1.0], [3.0, 3.0]]}
    assert (
        "bbox"
        in rfc7946.problems(
            {
                "type": "FeatureCollection",
                "bbox": [0, 0, 2, 2],
                "features": [{"type": "Feature", "geometry": line, "properties": {}}],
            }  # fmt: skip
        )[0]
    )
    assert rfc7946.problems({"type": "FeatureCollection", "features": [{"type": "Feature"}]})
    assert rfc7946.problems({"type": "Point", "coordinates": [float("nan"), 0.0]})


# ---------------------------------------------------------------------------------------- projection


def test_lonlat_of_inverts_project() -> None:
    net = small_network()
    rng = np.random.default_rng(7)
    lon = 104.0 + rng.random(50) * 0.2
    lat = 30.6 + rng.random(50) * 0.2
    x, y = net.project(lon, lat)
    back_lon, back_lat = lonlat_of(net.crs, x, y)
    assert np.abs(back_lon - lon).max() < 1e-9
    assert np.abs(back_lat - lat).max() < 1e-9
    grid_lon, grid_lat = lonlat_of(net.crs, x.reshape(5, 10), y.reshape(5, 10))
    assert grid_lon.shape == (5, 10)
    with pytest.raises(ValueError, match="same shape"):
        lonlat_of(net.crs, x, y[:3])


# ------------------------------------------------------------------------------------------ network


def test_network_edges_are_linestrings_tail_to_head() -> None:
    net = small_network()
    doc = network_geojson(net)
    assert rfc7946.problems(doc) == []
    feats = doc["features"]
    assert len(feats) == net.n_edges == 5
    ids = net.node_ids.tolist()
    for e, f in enumerate(feats):
        u, v = int(net.edge_u[e]), int(net.edge_v[e])
        assert f["id"] == f["properties"]["id"] == e
        assert (f["properties"]["u"], f["properties"]["v"]) == (ids[u], ids[v])
        assert f["geometry"]["coordinates"] == [
            [round(float(net.lon[u]), DECIMALS), round(float(net.lat[u]), DECIMALS)],
            [round(float(net.lon[v]), DECIMALS), round(float(net.lat[v]), DECIMALS)],
        ]
        assert f["properties"]["length_m"] == float(net.edge_length_m[e])
        assert f["properties"]["travel_time_s"] == pytest.approx(net.edge_length_m[e] / (35.0 / 3.6))
    # the edge 3 -> 4 exists one way only
    assert [(f["properties"]["u"], f["properties"]["v"]) for f in feats].count((4, 3)) == 0
    assert doc["bbox"] == [104.06, 30.65, 104.081, 30.659]


def test_network_of_a_bundled_city_is_valid_and_complete() -> None:
    city = bundled("manhattan")
    doc = network_geojson(city.network)
    assert rfc7946.problems(doc) == []
    assert len(doc["features"]) == city.network.n_edges
    total_m = sum(f["properties"]["length_m"] for f in doc["features"])
    assert total_m == pytest.approx(float(city.network.edge_length_m.sum()))
    json.dumps(doc, allow_nan=False)


# --------------------------------------------------------------------------------------------- grid


def _grid_corners_m(grid: Grid) -> np.ndarray:
    """Projected corners of every cell's ring (the definition in services.sensing.grid), (n_cells, 5, 2)."""
    col = np.arange(grid.n_cells) % grid.n_cols
    row = np.arange(grid.n_cells) // grid.n_cols
    dc = np.array([0, 1, 1, 0, 0])
    dr = np.array([0, 0, 1, 1, 0])
    x = grid.origin_x_m + (col[:, None] + dc) * grid.cell_m
    y = grid.origin_y_m + (row[:, None] + dr) * grid.cell_m
    return np.stack([x, y], axis=-1)


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_cell_rings_project_back_onto_the_grid(name: str) -> None:
    grid = bundled(name).grid
    rings = cell_rings(grid)
    assert rings.shape == (grid.n_cells, 5, 2)
    forward = Transformer.from_crs("EPSG:4326", grid.crs, always_xy=True)
    x, y = forward.transform(rings[..., 0], rings[..., 1])
    want = _grid_corners_m(grid)
    assert np.abs(x - want[..., 0]).max() < ROUND_M
    assert np.abs(y - want[..., 1]).max() < ROUND_M
    # closed, and neighbours share corners exactly: east neighbour's west side, north neighbour's south side
    assert (rings[:, 0] == rings[:, 4]).all()
    c = np.arange(grid.n_cells)
    east = c[(c % grid.n_cols) < grid.n_cols - 1]
    assert (rings[east, 1] == rings[east + 1, 0]).all() and (rings[east, 2] == rings[east + 1, 3]).all()
    north = c[c < grid.n_cells - grid.n_cols]
    assert (rings[north, 3] == rings[north + grid.n_cols, 0]).all()


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_cells_are_one_square_kilometre_counterclockwise(name: str) -> None:
    grid = bundled(name).grid
    for ring in cell_rings(grid):
        area_m2, perimeter_m = GEOD.polygon_area_perimeter(ring[:, 0], ring[:, 1])
        # pyproj gives a positive area for a counterclockwise ring; UTM's scale is 1 +- 0.1 % here
        assert 0.998e6 < area_m2 < 1.002e6
        assert 3996.0 < perimeter_m < 4004.0


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_every_node_lies_in_the_polygon_of_its_cell(name: str) -> None:
    city = bundled(name)
    net, grid = city.network, city.grid
    rings = cell_rings(grid)
    cell = cells_of_points(grid, net.x_m, net.y_m)
    quad = rings[cell, :4]  # (n, 4, 2), counterclockwise
    a, b = quad, np.roll(quad, -1, axis=1)
    p = np.stack([net.lon, net.lat], axis=-1)[:, None, :]
    edge = b - a
    cross = edge[..., 0] * (p[..., 1] - a[..., 1]) - edge[..., 1] * (p[..., 0] - a[..., 0])
    dist_deg = cross / np.hypot(edge[..., 0], edge[..., 1])  # signed distance to each side, inside > 0
    assert dist_deg.min() > -1.5 * 10.0**-DECIMALS  # only rounding can put a node on the wrong side
    assert (dist_deg.min(axis=1) > 0).mean() > 0.99


def test_grid_features_carry_counts_and_weights() -> None:
    city = bundled("chengdu")
    grid = city.grid
    counts = np.zeros(grid.n_cells, dtype=np.int64)
    counts[[0, 5, grid.n_cells - 1]] = [3, 1, 2]
    doc = grid_geojson(grid, counts, city.cell_weight)
    assert rfc7946.problems(doc) == []
    feats = doc["features"]
    assert len(feats) == grid.n_cells == 110
    assert [f["id"] for f in feats] == list(range(grid.n_cells))
    sensed = {f["properties"]["cell"]: f["properties"]["lambda"] for f in feats if f["properties"]["sensed"]}
    assert sensed == {0: 3, 5: 1, grid.n_cells - 1: 2}
    f5 = feats[5]["properties"]
    assert (f5["col"], f5["row"]) == grid.col_row(5) == (5, 0)
    assert sum(f["properties"]["weight"] for f in feats) == pytest.approx(1.0)
    assert sum(f["properties"]["weight"] > 0 for f in feats) == int(np.count_nonzero(city.cell_weight))
    ring = feats[5]["geometry"]["coordinates"][0]
    assert ring == cell_rings(grid)[5].tolist()


def test_grid_rejects_counts_of_another_shape() -> None:
    grid = build_grid(small_network())
    with pytest.raises(ValueError, match="one entry per cell"):
        grid_geojson(grid, np.zeros(grid.n_cells + 1, dtype=np.int64), np.zeros(grid.n_cells))
    with pytest.raises(ValueError, match="non-negative integers"):
        grid_geojson(grid, -np.ones(grid.n_cells, dtype=np.int64), np.zeros(grid.n_cells))
    with pytest.raises(ValueError, match="non-negative integers"):
        grid_geojson(grid, np.full(grid.n_cells, 0.5), np.zeros(grid.n_cells))


# ------------------------------------------------------------------------------------------- routes

T = dt.datetime(2026, 11, 23, 8, 10, tzinfo=dt.timezone(dt.timedelta(hours=8))).timestamp()


def test_routes_of_an_epoch() -> None:
    net = small_network()
    i = {int(n): k for k, n in enumerate(net.node_ids)}
    match = RiderMatch(
        step=1, taxi_id=TaxiId("t1"), rider_id=RiderId("r1"), pickup_m=1005.0, wait_s=103.5, trip_m=998.0,
        trip_time_s=102.6, sensing_gain=0.25, path=(i[1], i[2], i[3]), cells=((0, 0), (1, 0)),
    )  # fmt: skip
    still = RiderMatch(
        step=2, taxi_id=TaxiId("t2"), rider_id=RiderId("r2"), pickup_m=0.0, wait_s=0.0, trip_m=0.0,
        trip_time_s=0.0, sensing_gain=0.0, path=(i[4],), cells=((1, 1),),
    )  # fmt: skip
    route = TaskAssignment(
        taxi_id=TaxiId("t3"), task_id=TaskId("poi-1"), path=(i[3], i[4]), cells=((1, 1),), length_m=1004.0,
        travel_time_s=103.3, sensing_gain=0.5, efficiency=float("inf"), cost_cny=1.5, kappa=0.3,
    )  # fmt: skip
    tasks = [
        Task(TaskId("poi-1"), i[4], T - 60.0, "assigned", T + 103.3, TaxiId("t3"), "active"),
        Task(TaskId("poi-2"), i[2], T - 600.0),
    ]
    doc = routes_geojson(net, T, "Asia/Shanghai", [match, still], [route], tasks)
    assert rfc7946.problems(doc) == []
    rider, parked, poi, task1, task2 = doc["features"]

    assert rider["geometry"]["type"] == "LineString"
    assert rider["geometry"]["coordinates"] == [[104.06, 30.65], [104.0705, 30.65], [104.0705, 30.659]]
    assert rider["properties"] == {
        "kind": "rider", "step": 1, "taxi_id": "t1", "rider_id": "r1", "sensing_gain": 0.25,
        "pickup_m": 1005.0, "wait_s": 103.5, "trip_m": 998.0, "trip_time_s": 102.6,
        "depart_at": "2026-11-23T08:10:00+08:00", "pickup_at": "2026-11-23T08:11:43.500000+08:00",
        "dropoff_at": "2026-11-23T08:13:26.100000+08:00",
    }  # fmt: skip
    assert parked["geometry"] == {"type": "Point", "coordinates": [104.081, 30.659]}
    assert parked["properties"]["step"] == 2

    assert poi["geometry"]["coordinates"] == [[104.0705, 30.659], [104.081, 30.659]]
    assert poi["properties"]["kind"] == "poi" and poi["properties"]["step"] == 3
    assert poi["properties"]["task_id"] == "poi-1"
    assert poi["properties"]["efficiency"] is None  # not a finite number: JSON has no infinity
    assert poi["properties"]["arrive_at"] == "2026-11-23T08:11:43.300000+08:00"

    assert task1["geometry"] == {"type": "Point", "coordinates": [104.081, 30.659]}
    assert task1["properties"] == {
        "kind": "task", "task_id": "poi-1", "node": 4, "status": "assigned",
        "scheduled_at": "2026-11-23T08:09:00+08:00", "completed_at": "2026-11-23T08:11:43.300000+08:00",
        "taxi_id": "t3", "mode": "active",
    }  # fmt: skip
    assert task2["properties"]["status"] == "pending" and task2["properties"]["completed_at"] is None
    json.dumps(doc, allow_nan=False)


def test_routes_of_an_empty_epoch() -> None:
    doc = routes_geojson(small_network(), T, "UTC", [], [], [])
    assert doc == {"type": "FeatureCollection", "features": []}


def test_an_unknown_trip_time_is_null_not_a_guess() -> None:
    net = small_network()
    i = {int(n): k for k, n in enumerate(net.node_ids)}
    match = RiderMatch(
        step=2, taxi_id=TaxiId("t1"), rider_id=RiderId("r1"), pickup_m=0.0, wait_s=30.0, trip_m=998.0,
        trip_time_s=float("nan"), sensing_gain=0.0, path=(i[2], i[3]), cells=((1, 0),),
    )  # fmt: skip
    (feature,) = routes_geojson(net, T, "Asia/Shanghai", [match], [], [])["features"]
    p = feature["properties"]
    assert p["pickup_at"] == "2026-11-23T08:10:30+08:00"
    assert p["trip_time_s"] is None and p["dropoff_at"] is None
