"""The generated metropolitan city of the benchmarks (``bench/metro.py``), built small (``scale`` 0.18, about
9,000 nodes): one strongly connected network, the same for a seed, with a road hierarchy, one-way streets,
dead ends and bends, a river crossed only on a few bridges, and demand drawn around its dense centres."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as cg
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from bench import metro
from services.city import City
from services.citydata import haversine_m
from services.network.network import Network

SCALE = 0.18


@pytest.fixture(scope="module")
def city() -> City:
    return metro.metro_city(metro.SEED, SCALE)


def _kmh(net: Network) -> NDArray[np.float64]:
    return np.round(net.edge_length_m / net.edge_time_s * 3.6)


def _has_reverse(net: Network) -> NDArray[np.bool_]:
    n = net.n_nodes
    u, v = net.edge_u.astype(np.int64), net.edge_v.astype(np.int64)
    return np.isin(v * n + u, u * n + v)


def _neighbours(net: Network) -> NDArray[np.int64]:
    """Distinct neighbours of every node, either direction."""
    n = net.n_nodes
    u, v = net.edge_u.astype(np.int64), net.edge_v.astype(np.int64)
    pairs = np.unique(np.minimum(u, v) * n + np.maximum(u, v))
    return np.bincount(pairs // n, minlength=n) + np.bincount(pairs % n, minlength=n)


def _north_of_river(net: Network, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Whether projected points lie north of the river's centre line."""
    line = metro.river(metro.SEED, SCALE)
    rx, ry = net.project(line[:, 0], line[:, 1])
    assert np.all(np.diff(rx) > 0)  # a function of x: west to east
    return np.asarray(y > np.interp(x, rx, ry))


def test_a_small_city_is_one_strongly_connected_network_of_the_size_asked() -> None:
    """Every node reaches every other; ~9,000 nodes on a 12.6 km square, 2.5-2.9 directed edges a node."""
    net = metro.metro_city(metro.SEED, SCALE).network
    assert 6_000 <= net.n_nodes <= 12_000
    assert 2.5 <= net.n_edges / net.n_nodes <= 2.9
    adj = net.csr(np.ones(net.n_edges))
    assert cg.connected_components(adj, connection="strong")[0] == 1
    side_km = metro.SIDE_M * SCALE / 1000.0
    for extent in (np.ptp(net.x_m), np.ptp(net.y_m)):
        assert 0.97 * side_km <= extent / 1000.0 <= 1.03 * side_km


def test_the_same_seed_gives_the_same_city_and_another_seed_another(city: City) -> None:
    net, again = city.network, metro.metro_city(metro.SEED, SCALE).network
    for name in ("node_ids", "lon", "lat", "edge_u", "edge_v", "edge_length_m", "edge_time_s"):
        assert np.array_equal(getattr(net, name), getattr(again, name)), name
    other = metro.metro_city(metro.SEED + 1, SCALE).network
    assert other.n_nodes != net.n_nodes or not np.array_equal(other.lon, net.lon)


def test_the_road_classes_are_few_motorway_edges_some_arterials_and_mostly_local_streets(city: City) -> None:
    """Speeds are the classes' (30 local, 40 ramp, 50 arterial, 60 country road, 90 motorway); motorways are
    dual carriageways (every edge one-way), arterials and country roads two-way."""
    net = city.network
    kmh = _kmh(net)
    assert set(np.unique(kmh).tolist()) == {30.0, 40.0, 50.0, 60.0, 90.0}
    share = {k: float((kmh == k).mean()) for k in (30.0, 40.0, 50.0, 60.0, 90.0)}
    assert 0.0 < share[90.0] < 0.05
    assert 0.0 < share[40.0] < share[90.0]
    assert 0.05 < share[50.0] + share[60.0] < 0.3
    assert share[30.0] > 0.65
    rev = _has_reverse(net)
    assert not rev[kmh == 90.0].any()
    assert rev[(kmh == 50.0) | (kmh == 60.0)].all()


def test_streets_are_irregular_with_one_way_streets_dead_ends_bends_and_chains(city: City) -> None:
    """10-20 % of the local streets one-way, dead ends, T-junctions, degree-2 chains; every edge 0-30 %
    longer than the straight line between its ends."""
    net = city.network
    kmh = _kmh(net)
    rev = _has_reverse(net)
    local = kmh == 30.0
    one_way_streets = int((~rev & local).sum())
    streets = int((rev & local).sum()) // 2 + one_way_streets
    assert 0.08 <= one_way_streets / streets <= 0.22
    nbrs = _neighbours(net)
    assert 0.02 <= (nbrs == 1).mean() <= 0.12  # dead ends
    assert 0.2 <= (nbrs == 2).mean() <= 0.45  # shape nodes along bends, corners
    assert (nbrs == 3).mean() >= 0.15  # T-junctions
    assert (nbrs >= 4).mean() >= 0.15
    u, v = net.edge_u, net.edge_v
    ratio = net.edge_length_m / haversine_m(net.lon[u], net.lat[u], net.lon[v], net.lat[v])
    assert ratio.min() >= 1.0 - 1e-9 and ratio.max() <= 1.3 + 1e-6
    assert 1.05 <= ratio.mean() <= 1.15


def test_node_density_is_high_at_the_centres_and_low_in_the_country(city: City) -> None:
    net = city.network
    c = metro.centres(city)
    assert 4 <= c.shape[0] <= 6
    mean_density = net.n_nodes / (np.ptp(net.x_m) * np.ptp(net.y_m))
    tree = cKDTree(np.column_stack([net.x_m, net.y_m]))
    radius = 600.0
    for x, y in c:
        near = len(tree.query_ball_point([x, y], radius))
        assert near / (np.pi * radius**2) > 1.8 * mean_density

    def far(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.bool_]:
        d = np.hypot(x[:, None] - c[None, :, 0], y[:, None] - c[None, :, 1]).min(axis=1)
        return np.asarray(d > 0.22 * metro.SIDE_M * SCALE)

    # the country's area from a fine lattice over the bounding box
    gx, gy = np.meshgrid(
        np.linspace(net.x_m.min(), net.x_m.max(), 200), np.linspace(net.y_m.min(), net.y_m.max(), 200)
    )
    country_area = far(gx.ravel(), gy.ravel()).mean() * np.ptp(net.x_m) * np.ptp(net.y_m)
    assert country_area > 0.2 * np.ptp(net.x_m) * np.ptp(net.y_m)
    assert far(net.x_m, net.y_m).sum() / country_area < 0.45 * mean_density


def test_the_river_is_crossed_only_on_a_few_bridges_so_routes_detour(city: City) -> None:
    """Edges across the river (checked along each edge, not only at its ends) lie at 3-10 places, all
    arterials, country roads or motorways; nodes close across the river are far apart by road."""
    net = city.network
    u, v = net.edge_u, net.edge_v
    north = _north_of_river(net, net.x_m, net.y_m)
    assert 0.25 <= north.mean() <= 0.75
    across = north[u] != north[v]
    t = np.linspace(0.0, 1.0, 11)[:, None]
    sampled = _north_of_river(
        net,
        (net.x_m[u] + t * (net.x_m[v] - net.x_m[u])).ravel(),
        (net.y_m[u] + t * (net.y_m[v] - net.y_m[u])).ravel(),
    ).reshape(t.size, -1)
    assert np.array_equal(sampled.any(axis=0) & ~sampled.all(axis=0), across)
    assert set(np.unique(_kmh(net)[across]).tolist()) <= {50.0, 60.0, 90.0}

    mid = 0.5 * np.column_stack([net.x_m[u] + net.x_m[v], net.y_m[u] + net.y_m[v]])[across]
    pairs = cKDTree(mid).query_pairs(300.0, output_type="ndarray")
    adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(mid),) * 2)
    n_places, label = cg.connected_components(adj, directed=False)
    assert 3 <= n_places <= 10
    assert n_places == len(metro.river_crossings(city, metro.SEED, SCALE))
    count = np.bincount(label)
    places = np.column_stack([np.bincount(label, mid[:, 0]) / count, np.bincount(label, mid[:, 1]) / count])

    # nodes near the river, away from every crossing, and their nearest node on the other bank
    xy = np.column_stack([net.x_m, net.y_m])
    to_crossing, _ = cKDTree(places).query(xy)
    line = metro.river(metro.SEED, SCALE)
    rx, ry = net.project(line[:, 0], line[:, 1])
    shore = (np.abs(net.y_m - np.interp(net.x_m, rx, ry)) < 500.0) & (to_crossing > 1_500.0)
    north_shore, south_shore = np.flatnonzero(shore & north), np.flatnonzero(shore & ~north)
    sources = np.random.default_rng(1).choice(north_shore, 6, replace=False)
    dist, nearest = cKDTree(xy[south_shore]).query(xy[sources])
    targets = south_shore[nearest]
    by_road = cg.dijkstra(net.csr(net.edge_length_m), indices=sources)[np.arange(sources.size), targets]
    assert np.all(dist < 900.0)
    midpoint = 0.5 * (xy[sources] + xy[targets])
    detour, _ = cKDTree(places).query(midpoint)
    assert np.all(by_road >= 2.0 * detour)  # over a bridge: no hidden way across
    assert np.all(by_road > 3.0 * dist)


def test_near_centres_draws_valid_nodes_concentrated_around_the_centres(city: City) -> None:
    net = city.network
    spread = 2_500.0 * SCALE
    idx = metro.near_centres(city, np.random.default_rng(5), 3_000, spread_m=spread)
    assert idx.shape == (3_000,) and idx.dtype == np.int64
    assert idx.min() >= 0 and idx.max() < net.n_nodes
    assert np.array_equal(idx, metro.near_centres(city, np.random.default_rng(5), 3_000, spread_m=spread))
    c = metro.centres(city)

    def to_centre(nodes: NDArray[np.int64]) -> NDArray[np.float64]:
        d = np.hypot(net.x_m[nodes, None] - c[None, :, 0], net.y_m[nodes, None] - c[None, :, 1])
        return np.asarray(d.min(axis=1))

    uniform = np.random.default_rng(6).integers(0, net.n_nodes, 3_000)
    assert np.median(to_centre(idx)) < 0.4 * np.median(to_centre(uniform))
    assert np.median(to_centre(idx)) < 1.5 * spread
    # the main centre draws the most
    main = np.hypot(net.x_m[idx] - c[0, 0], net.y_m[idx] - c[0, 1]) < 2.5 * spread
    assert 0.3 <= main.mean() <= 0.6


def test_the_full_city_is_a_metropolitan_network_of_over_250k_nodes() -> None:
    """At scale 1: 255-275k nodes, 2.6-2.9 directed edges a node, over 70 x 70 km."""
    t = metro.describe(metro.metro_city())
    assert 255_000 <= t["nodes"] <= 275_000
    assert 2.6 <= t["edges_per_node"] <= 2.9
    assert t["width_km"] >= 68.0 and t["height_km"] >= 68.0
    assert 0 < t["motorway_edges"] < 0.01 * t["edges"] < t["arterial_edges"] < t["local_edges"]
