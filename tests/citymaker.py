"""Build small cities in exact metric coordinates for hand-solvable tests (no projection involved)."""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping, Sequence

import numpy as np

from services.city import City, DispatchParams, Horizon
from services.network.network import Network
from services.sensing.grid import build_edge_cells, build_grid, touched_cells

T0 = dt.datetime(2026, 11, 23, 8, 0, tzinfo=dt.UTC).timestamp()
"""08:00 UTC: the start of the first horizon interval for cities made here (timezone UTC)."""


def make_city(
    nodes: Mapping[int, tuple[float, float]],
    edges: Sequence[tuple[int, int]] | Sequence[tuple[int, int, float]],
    *,
    speed_kmh: float = 36.0,
    both_ways: bool = True,
    cell_m: float = 1000.0,
    params: DispatchParams | None = None,
    horizon: Horizon | None = None,
    cell_weight: Mapping[tuple[int, int], float] | None = None,
) -> City:
    """A city whose node ``i`` sits at metric ``nodes[i] = (x, y)``; edge lengths default to the straight
    distance. At 36 km/h an edge of 10 m takes 1 s."""
    ids = np.array(sorted(nodes), dtype=np.int64)
    index = {int(n): i for i, n in enumerate(ids)}
    x = np.array([nodes[int(n)][0] for n in ids], dtype=np.float64)
    y = np.array([nodes[int(n)][1] for n in ids], dtype=np.float64)
    rows: dict[tuple[int, int], float] = {}
    for e in edges:
        u, v = index[e[0]], index[e[1]]
        length = float(e[2]) if len(e) > 2 else float(np.hypot(x[v] - x[u], y[v] - y[u]))
        pairs = [(u, v), (v, u)] if both_ways else [(u, v)]
        for a, b in pairs:
            rows[(a, b)] = min(length, rows.get((a, b), np.inf))
    keys = sorted(rows)
    eu = np.array([k[0] for k in keys], dtype=np.int32)
    ev = np.array([k[1] for k in keys], dtype=np.int32)
    length_m = np.array([rows[k] for k in keys], dtype=np.float64)
    indptr = np.zeros(len(ids) + 1, dtype=np.int64)
    np.add.at(indptr, eu.astype(np.int64) + 1, 1)
    net = Network(
        node_ids=ids,
        lon=x / 1e5,
        lat=y / 1e5,
        x_m=x,
        y_m=y,
        crs="LOCAL",
        edge_u=eu,
        edge_v=ev,
        edge_length_m=length_m,
        edge_time_s=length_m / (speed_kmh / 3.6),
        indptr=np.cumsum(indptr),
    )
    grid = build_grid(net, cell_m)
    ec = build_edge_cells(grid, net)
    weight = np.zeros(grid.n_cells)
    if cell_weight is None:
        weight[touched_cells(grid, net, ec)] = 1.0
    else:
        for (c, r), w in cell_weight.items():
            weight[r * grid.n_cols + c] = w
    weight /= weight.sum()
    hz = horizon or Horizon(timezone="UTC")
    return City(
        name="test",
        network=net,
        grid=grid,
        edge_cells=ec,
        horizon=hz,
        params=params or DispatchParams(speed_kmh=speed_kmh),
        cell_weight=weight,
        interval_weight=np.full(hz.n_intervals, 1.0 / hz.n_intervals),
    )


def grid_city(n: int, spacing_m: float, **kw: object) -> City:
    """An ``n x n`` lattice of two-way streets, node id ``row * n + col`` at ``(col, row) * spacing``."""
    nodes = {r * n + c: (c * spacing_m, r * spacing_m) for r in range(n) for c in range(n)}
    edges = [(r * n + c, r * n + c + 1) for r in range(n) for c in range(n - 1)]
    edges += [(r * n + c, (r + 1) * n + c) for r in range(n - 1) for c in range(n)]
    return make_city(nodes, edges, **kw)  # type: ignore[arg-type]
