"""The sensing grid: point cells, exact segment crossings, edge cells and G-routes."""

from __future__ import annotations

import numpy as np
import pytest

from services.network.network import Network, build_network
from services.sensing.grid import (
    EdgeCells,
    Grid,
    build_edge_cells,
    build_grid,
    cells_of_points,
    node_col_row,
    path_cells,
    segment_cells,
    touched_cells,
)

G = Grid(crs="EPSG:32648", origin_x_m=0.0, origin_y_m=0.0, cell_m=1000.0, n_cols=4, n_rows=4)


def cells(x0: float, y0: float, x1: float, y1: float) -> tuple[list[int], list[float]]:
    c, f = segment_cells(G, x0, y0, x1, y1)
    return c.tolist(), f.tolist()


def cr(c: int) -> tuple[int, int]:
    return G.col_row(c)


def test_cell_of_point_rule() -> None:
    assert cells_of_points(G, [0.0, 999.9, 1000.0, 3999.0], [0.0, 0.0, 1000.0, 2500.0]).tolist() == [
        0,
        0,
        5,
        11,
    ]
    with pytest.raises(ValueError, match="outside the grid"):
        cells_of_points(G, [4000.0], [0.0])
    with pytest.raises(ValueError, match="outside the grid"):
        cells_of_points(G, [-0.1], [0.0])


def test_horizontal_through_two_cells() -> None:
    assert cells(500.0, 500.0, 1500.0, 500.0) == ([0, 1], [0.0, 0.5])
    # and backwards
    assert cells(1500.0, 500.0, 500.0, 500.0) == ([1, 0], [0.0, 0.5])


def test_horizontal_through_three_cells() -> None:
    c, f = cells(250.0, 1500.0, 2750.0, 1500.0)
    assert [cr(x) for x in c] == [(0, 1), (1, 1), (2, 1)]
    assert f == pytest.approx([0.0, 0.3, 0.7])


def test_diagonal_exactly_through_corner_skips_side_cells() -> None:
    c, f = cells(500.0, 500.0, 1500.0, 1500.0)
    assert [cr(x) for x in c] == [(0, 0), (1, 1)]
    assert f == [0.0, 0.5]
    # the anti-diagonal through two corners
    c, f = cells(2900.0, 100.0, 100.0, 2900.0)
    assert [cr(x) for x in c] == [(2, 0), (1, 1), (0, 2)]
    assert f == pytest.approx([0.0, 900 / 2800, 1900 / 2800])


def test_segment_on_grid_line_takes_cells_above_or_right() -> None:
    # on the horizontal line y = 1000: midpoints have row 1
    c, f = cells(500.0, 1000.0, 2500.0, 1000.0)
    assert [cr(x) for x in c] == [(0, 1), (1, 1), (2, 1)]
    assert f == pytest.approx([0.0, 0.25, 0.75])
    # on the vertical line x = 2000, downwards: column 2
    c, f = cells(2000.0, 1500.0, 2000.0, 500.0)
    assert [cr(x) for x in c] == [(2, 1), (2, 0)]
    assert f == [0.0, 0.5]


def test_zero_length_segment_is_its_tails_cell() -> None:
    assert cells(1000.0, 1000.0, 1000.0, 1000.0) == ([5], [0.0])
    assert cells(1234.0, 2345.0, 1234.0, 2345.0) == ([9], [0.0])


def test_starting_exactly_on_a_line() -> None:
    # starts on x = 1000 and moves left: only column 0
    assert cells(1000.0, 500.0, 500.0, 500.0) == ([0], [0.0])
    # starts on x = 1000 and moves right: only column 1
    assert cells(1000.0, 500.0, 1500.0, 500.0) == ([1], [0.0])
    # starts on the corner (1000, 1000) and goes down-left
    assert cells(1000.0, 1000.0, 500.0, 500.0) == ([0], [0.0])
    # ends exactly on a line: that line adds nothing
    assert cells(500.0, 500.0, 1000.0, 500.0) == ([0], [0.0])


def _sampled_runs(x0: float, y0: float, x1: float, y1: float, n: int) -> list[int]:
    s = (np.arange(n) + 0.5) / n
    c = cells_of_points(G, x0 + s * (x1 - x0), y0 + s * (y1 - y0))
    keep = np.ones(c.size, dtype=bool)
    keep[1:] = c[1:] != c[:-1]
    return [int(x) for x in c[keep]]


def test_random_segments_agree_with_dense_sampling() -> None:
    rng = np.random.default_rng(20240611)
    for _ in range(400):
        x0, y0, x1, y1 = rng.uniform(1.0, 3999.0, 4)
        c, f = segment_cells(G, x0, y0, x1, y1)
        length = float(np.hypot(x1 - x0, y1 - y0))
        # sampling every ~0.05 m sees every piece longer than that; pieces near corners can be shorter
        got = _sampled_runs(x0, y0, x1, y1, max(2, int(length / 0.05)))
        if got != c.tolist():
            # only acceptable difference: a sliver (< 0.1 m) the sampling missed
            s_bounds = np.append(f, 1.0)
            assert min(np.diff(s_bounds) * length) < 0.1, (x0, y0, x1, y1, c, got)
            assert set(got) <= set(c.tolist())
            continue
        assert f[0] == 0.0 and np.all(np.diff(f) > 0)
        # each run starts where the sampled points change cell
        for k in range(1, len(f)):
            s = f[k]
            px, py = x0 + (s + 1e-9) * (x1 - x0), y0 + (s + 1e-9) * (y1 - y0)
            assert cells_of_points(G, [px], [py]).tolist() == [c[k]]


def test_frac_is_where_the_run_starts() -> None:
    c, f = cells(100.0, 100.0, 3100.0, 1100.0)
    # crosses x = 1000 at s = 0.3, x = 2000 at s = 19/30, y = 1000 at s = 0.9, x = 3000 at s = 29/30
    assert [cr(x) for x in c] == [(0, 0), (1, 0), (2, 0), (2, 1), (3, 1)]
    assert f == pytest.approx([0.0, 0.3, 19 / 30, 0.9, 29 / 30])


def _net() -> tuple[Grid, Network]:
    # nodes at known projected positions: build in lon/lat, then use the network's own projection
    lon = [104.0, 104.012, 104.012, 104.0]
    lat = [30.0, 30.0, 30.012, 30.012]
    net = build_network([1, 2, 3, 4], lon, lat, [1, 2, 3, 4, 1], [2, 3, 4, 1, 3], [1.0] * 5)
    return build_grid(net), net


def test_build_grid_covers_every_node() -> None:
    grid, net = _net()
    assert grid.origin_x_m % 1000.0 == 0 and grid.origin_y_m % 1000.0 == 0
    assert grid.origin_x_m <= net.x_m.min() < grid.origin_x_m + 1000.0
    c = cells_of_points(grid, net.x_m, net.y_m)
    assert c.min() >= 0 and c.max() < grid.n_cells
    # 1.15 km wide, 1.33 km tall: 2 or 3 columns, 2 or 3 rows depending on the origin
    assert grid.n_cols in (2, 3) and grid.n_rows in (2, 3)
    assert grid.crs == "EPSG:32648"


def test_build_grid_node_on_last_line_gets_its_own_column() -> None:
    net = build_network([1, 2], [104.0, 104.01], [30.0, 30.0], [1, 2], [2, 1], [1.0, 1.0])
    grid = build_grid(net, cell_m=10.0)
    cells = cells_of_points(grid, net.x_m, net.y_m)
    assert cells.min() >= 0 and cells.max() < grid.n_cells
    cols = cells % grid.n_cols
    east = int(np.argmax(net.x_m))
    # the easternmost node lies in the last column, inside its bounds (not clipped onto the one before)
    assert cols[east] == grid.n_cols - 1 and cols[1 - east] == 0
    col, row = node_col_row(grid, net)
    assert col.tolist() == cols.tolist() and (row * grid.n_cols + col).tolist() == cells.tolist()
    left = grid.origin_x_m + (grid.n_cols - 1) * grid.cell_m
    assert left <= net.x_m[east] < left + grid.cell_m


def test_edge_cells_match_segment_cells() -> None:
    grid, net = _net()
    ec = build_edge_cells(grid, net)
    assert ec.ptr.size == net.n_edges + 1
    for e in range(net.n_edges):
        u, v = net.edge_u[e], net.edge_v[e]
        c, f = segment_cells(grid, net.x_m[u], net.y_m[u], net.x_m[v], net.y_m[v])
        assert ec.cell[ec.ptr[e] : ec.ptr[e + 1]].tolist() == c.tolist()
        assert ec.frac[ec.ptr[e] : ec.ptr[e + 1]].tolist() == f.tolist()
    touched = touched_cells(grid, net, ec)
    assert touched.tolist() == sorted(set(touched.tolist()))
    assert set(ec.cell.tolist()) <= set(touched.tolist())


def test_path_cells_first_entry_order() -> None:
    ec = EdgeCells(
        ptr=np.array([0, 2, 3, 5], dtype=np.int64),
        cell=np.array([4, 5, 5, 9, 4], dtype=np.int32),
        frac=np.array([0.0, 0.4, 0.0, 0.0, 0.7]),
    )
    assert path_cells(ec, [0, 1, 2]) == [4, 5, 9]
    assert path_cells(ec, [2, 0]) == [9, 4, 5]
    assert path_cells(ec, []) == []


def test_edge_cells_of_a_large_network_equal_the_per_edge_rule() -> None:
    """The vectorized pass over 15,000 edges (one sort over every breakpoint of every edge) gives each edge
    exactly the cells and fractions of that edge alone, and the nodes' cells are those of the point rule."""
    rng = np.random.default_rng(3)
    n, m = 8000, 15000
    lon = rng.uniform(104.04, 104.13, n)
    lat = rng.uniform(30.65, 30.73, n)
    u = rng.integers(0, n, m)
    v = np.clip(u + rng.integers(-50, 50, m), 0, n - 1)
    net = build_network(np.arange(n), lon, lat, u, v, np.ones(m))
    grid = build_grid(net)
    ec = build_edge_cells(grid, net)
    assert ec.ptr[0] == 0 and ec.ptr[-1] == ec.cell.size and np.all(np.diff(ec.ptr) >= 1)
    for e in range(net.n_edges):
        a, b = net.edge_u[e], net.edge_v[e]
        c, f = segment_cells(grid, net.x_m[a], net.y_m[a], net.x_m[b], net.y_m[b])
        assert np.array_equal(ec.cell[ec.ptr[e] : ec.ptr[e + 1]], c), e
        assert np.array_equal(ec.frac[ec.ptr[e] : ec.ptr[e + 1]], f), e
    col, row = node_col_row(grid, net)
    assert np.array_equal(row * grid.n_cols + col, cells_of_points(grid, net.x_m, net.y_m))
