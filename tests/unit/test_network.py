"""Network construction, strongly connected components, snapping and edge lookup on hand-built networks."""

from __future__ import annotations

import numpy as np
import pytest

from services.network.network import (
    Network,
    SnapError,
    build_network,
    largest_strongly_connected,
    utm_crs,
)

# four nodes on a ~111 m square near Chengdu; ids deliberately not 0..n-1 nor sorted
IDS = [40, 10, 30, 20]
LON = [104.0000, 104.0010, 104.0010, 104.0000]
LAT = [30.0000, 30.0000, 30.0010, 30.0010]


def square(**kw: object) -> Network:
    # a directed cycle 40 -> 10 -> 30 -> 20 -> 40, plus a parallel 40 -> 10 and a self-loop on 30
    u = [40, 10, 30, 20, 40, 30]
    v = [10, 30, 20, 40, 10, 30]
    length = [100.0, 110.0, 120.0, 130.0, 90.0, 5.0]
    return build_network(IDS, LON, LAT, u, v, length, **kw)  # type: ignore[arg-type]


def test_ids_map_to_indices_in_given_order() -> None:
    net = square()
    assert net.node_ids.tolist() == IDS
    assert [net.index_of(i) for i in IDS] == [0, 1, 2, 3]
    assert net.node_ids.dtype == np.int64 and net.edge_u.dtype == np.int32 and net.indptr.dtype == np.int64


def test_self_loops_dropped_parallel_keeps_shortest_edges_sorted() -> None:
    net = square()
    pairs = list(zip(net.edge_u.tolist(), net.edge_v.tolist(), strict=True))
    # 40->10 is (0,1); 10->30 (1,2); 30->20 (2,3); 20->40 (3,0)
    assert pairs == [(0, 1), (1, 2), (2, 3), (3, 0)]
    assert net.edge_length_m.tolist() == [90.0, 110.0, 120.0, 130.0]
    assert net.indptr.tolist() == [0, 1, 2, 3, 4]


def test_travel_time_from_speed() -> None:
    net = square()
    np.testing.assert_allclose(net.edge_time_s, net.edge_length_m / (35.0 / 3.6))
    fast = square(speed_kmh=[36.0, 72.0, 36.0, 36.0, 18.0, 36.0])
    # the kept 40->10 edge is the 90 m one at 18 km/h = 5 m/s
    assert fast.edge_time_s.tolist() == pytest.approx([18.0, 5.5, 12.0, 13.0])


def test_projection_is_utm_of_centroid() -> None:
    net = square()
    assert net.crs == "EPSG:32648"
    assert utm_crs(-73.97, 40.78) == "EPSG:32618"
    assert utm_crs(151.2, -33.9) == "EPSG:32756"
    # 0.001 deg of longitude at 30 N is about 96 m, of latitude about 111 m
    assert net.x_m[1] - net.x_m[0] == pytest.approx(96.3, abs=1.0)
    assert net.y_m[3] - net.y_m[0] == pytest.approx(110.9, abs=1.0)
    x, y = net.project(LON[2], LAT[2])
    assert (x, y) == pytest.approx((net.x_m[2], net.y_m[2]))


def test_build_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="duplicate node id 10"):
        build_network([10, 10], [0.0, 0.0], [0.0, 0.0], [], [], [])
    with pytest.raises(ValueError, match="unknown node id 99"):
        build_network([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [99], [1.0])
    with pytest.raises(ValueError, match="lat"):
        build_network([1], [0.0], [91.0], [], [], [])
    with pytest.raises(ValueError, match="finite"):
        build_network([1], [np.nan], [0.0], [], [], [])
    with pytest.raises(ValueError, match="non-negative"):
        build_network([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [2], [-1.0])
    with pytest.raises(ValueError, match="speeds"):
        build_network([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [2], [1.0], speed_kmh=[0.0])


def test_missing_speeds_take_the_default() -> None:
    net = square(speed_kmh=[36.0, 72.0, np.nan, 36.0, np.nan, 36.0], default_speed_kmh=18.0)
    # kept: 40->10 the 90 m edge at the default 18 km/h (5 m/s), 10->30 110 m at 20 m/s, 30->20 120 m at
    # the default, 20->40 130 m at 10 m/s
    assert net.edge_time_s.tolist() == pytest.approx([18.0, 5.5, 24.0, 13.0])


@pytest.mark.parametrize(
    ("args", "kw", "problem"),
    [
        (([], [], [], [], [], []), {}, "at least one node"),
        (([1, 2], [0.0], [0.0, 0.0], [], [], []), {}, "node_ids, lon and lat must have the same length"),
        (([1.5], [0.0], [0.0], [], [], []), {}, "node_ids must hold integers"),
        (([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [2, 1], [1.0]), {}, "edge_u_ids, edge_v_ids and length_m"),
        (([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [2], [1.0]), {"default_speed_kmh": 0.0}, "default_speed_kmh"),
        (
            ([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [2], [1.0]),
            {"speed_kmh": [30.0, 30.0]},
            "one entry per edge",
        ),
        (([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [2], [1.0]), {"speed_kmh": [np.inf]}, "positive and finite"),
        (([1, 2], [0.0, 0.0], [0.0, 0.0], [99], [2], [1.0]), {}, "edge_u_ids names unknown node id 99"),
        (([1, 2], [0.0, 0.0], [0.0, 0.0], [1], [98], [1.0]), {}, "edge_v_ids names unknown node id 98"),
    ],
)
def test_build_names_the_bad_input(
    args: tuple[list[float], ...], kw: dict[str, object], problem: str
) -> None:
    with pytest.raises(ValueError, match=problem):
        build_network(*args, **kw)  # type: ignore[arg-type]


def test_index_of_unknown_raises_snap_error() -> None:
    with pytest.raises(SnapError, match="unknown node id 11"):
        square().index_of(11)
    with pytest.raises(SnapError, match="unknown node id 10.5"):
        square().index_of(10.5)  # type: ignore[arg-type]
    assert square().index_of(np.int64(30)) == 2


def test_largest_strongly_connected() -> None:
    # SCC {1,2,3} (a cycle), SCC {4,5} (two-way), node 6 reachable only one way from 5
    ids = [1, 2, 3, 4, 5, 6]
    lon = [104.0 + 0.001 * i for i in range(6)]
    lat = [30.0] * 6
    u = [1, 2, 3, 3, 4, 5, 5]
    v = [2, 3, 1, 4, 5, 4, 6]
    net = build_network(ids, lon, lat, u, v, [1.0] * 7)
    scc = largest_strongly_connected(net)
    assert scc.node_ids.tolist() == [1, 2, 3]
    assert list(zip(scc.edge_u.tolist(), scc.edge_v.tolist(), strict=True)) == [(0, 1), (1, 2), (2, 0)]
    assert scc.indptr.tolist() == [0, 1, 2, 3]
    assert scc.x_m.tolist() == net.x_m[:3].tolist() and scc.crs == net.crs
    # an already strongly connected network comes back as is
    assert largest_strongly_connected(scc) is scc


def test_largest_strongly_connected_tie_takes_lowest_index() -> None:
    net = build_network(
        [1, 2, 3, 4], [0.0, 0.001, 0.002, 0.003], [0.0] * 4, [3, 4, 1, 2], [4, 3, 2, 1], [1.0] * 4
    )
    assert largest_strongly_connected(net).node_ids.tolist() == [1, 2]


def test_snap_within_and_beyond_limit() -> None:
    net = square()
    node, dist = net.snap(104.00101, 30.00101, limit_m=50.0)
    assert node == 2 and dist == pytest.approx(1.45, abs=0.2)
    with pytest.raises(SnapError, match=r"is \d+ m from the nearest node \(limit 50 m\)"):
        net.snap(104.01, 30.01, limit_m=50.0)
    with pytest.raises(SnapError, match="not a WGS84"):
        net.snap(200.0, 30.0, limit_m=50.0)


def test_snap_many_vectorized_names_offending_position() -> None:
    net = square()
    nodes, dist = net.snap_many([104.0, 104.001, 104.0], [30.0, 30.001, 30.00101], limit_m=10.0)
    assert nodes.tolist() == [0, 2, 3] and dist.shape == (3,)
    with pytest.raises(SnapError, match="position 1 "):
        net.snap_many([104.0, 104.5], [30.0, 30.0], limit_m=10.0)
    empty_nodes, _ = net.snap_many([], [], limit_m=10.0)
    assert empty_nodes.size == 0


def test_edge_ids() -> None:
    net = square()
    assert net.edge_ids([0, 1, 2, 3, 0]).tolist() == [0, 1, 2, 3]
    assert net.edge_ids(np.array([2, 3])).tolist() == [2]
    assert net.edge_ids([1]).tolist() == []
    with pytest.raises(ValueError, match="no edge from node 1 to node 0"):
        net.edge_ids([0, 1, 0])
    with pytest.raises(ValueError, match="out of range"):
        net.edge_ids([0, 7])


def test_edge_ids_random_paths_match_csr() -> None:
    rng = np.random.default_rng(1)
    n = 30
    u = rng.integers(0, n, 200)
    v = rng.integers(0, n, 200)
    net = build_network(
        np.arange(n) * 3,
        rng.uniform(104, 104.05, n),
        rng.uniform(30, 30.05, n),
        u * 3,
        v * 3,
        rng.uniform(1, 100, 200),
    )
    for e in rng.integers(0, net.n_edges, 50):
        a, b = int(net.edge_u[e]), int(net.edge_v[e])
        assert net.edge_ids([a, b]).tolist() == [e]
        assert net.indptr[a] <= e < net.indptr[a + 1]


def test_csr_and_bbox() -> None:
    net = square()
    m = net.csr(net.edge_length_m)
    assert m[0, 1] == 90.0 and m[3, 0] == 130.0 and m.nnz == 4
    assert net.bbox() == (104.0, 30.0, 104.001, 30.001)
