"""Idle drift: vacant taxis with no job move toward cells of high recent request density (docs/METHOD.md
section 10).

Each grid cell the network touches has a hub, the node nearest the cell's centre. One reverse shortest-path
tree per hub gives, for every node, the next node toward that hub and the remaining travel time, so a
drifting taxi moves with array look-ups instead of a search per taxi and epoch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.csgraph as cg
from numpy.typing import NDArray

from services.city import City

__all__ = ["DriftMap", "drift_map", "choose_target", "drift_walk"]


@dataclass(frozen=True, slots=True, eq=False)
class DriftMap:
    """Hubs of the touched cells and the shortest-path trees toward them.

    ``toward[h, u]`` is the node after ``u`` on a fastest path from ``u`` to hub ``h`` (``-1`` at the hub or
    when the hub cannot be reached); ``time_to[h, u]`` is that path's travel time in seconds.
    """

    cells: NDArray[np.int64]  # cell index of each hub
    hubs: NDArray[np.int64]  # node index of each hub
    center_x_m: NDArray[np.float64]
    center_y_m: NDArray[np.float64]
    toward: NDArray[np.int32]
    time_to: NDArray[np.float64]
    node_cell: NDArray[np.int64]  # cell of every node
    hub_of_cell: dict[int, int]  # cell -> row of the hub arrays


def drift_map(city: City) -> DriftMap:
    """Hubs and reverse shortest-path trees for every cell that holds at least one node."""
    net, grid = city.network, city.grid
    col = np.floor((net.x_m - grid.origin_x_m) / grid.cell_m).astype(np.int64)
    row = np.floor((net.y_m - grid.origin_y_m) / grid.cell_m).astype(np.int64)
    node_cell = row * grid.n_cols + col
    cells = np.unique(node_cell)
    hubs = np.empty(cells.size, dtype=np.int64)
    cx = np.empty(cells.size)
    cy = np.empty(cells.size)
    for i, c in enumerate(cells):
        members = np.flatnonzero(node_cell == c)
        cx[i] = grid.origin_x_m + (c % grid.n_cols + 0.5) * grid.cell_m
        cy[i] = grid.origin_y_m + (c // grid.n_cols + 0.5) * grid.cell_m
        d2 = (net.x_m[members] - cx[i]) ** 2 + (net.y_m[members] - cy[i]) ** 2
        hubs[i] = members[int(np.argmin(d2))]
    reverse = net.csr(net.edge_time_s).T.tocsr()
    dist, pred = cg.dijkstra(reverse, directed=True, indices=hubs, return_predecessors=True)
    toward = pred.astype(np.int32)
    toward[toward < 0] = -1
    return DriftMap(
        cells=cells,
        hubs=hubs,
        center_x_m=cx,
        center_y_m=cy,
        toward=toward,
        time_to=dist,
        node_cell=node_cell,
        hub_of_cell={int(c): i for i, c in enumerate(cells)},
    )


def choose_target(
    dm: DriftMap, node: int, density: NDArray[np.float64], radius_m: float, rng: np.random.Generator
) -> int:
    """Row of the hub a taxi at ``node`` drifts to: a cell within ``radius_m`` (centre to centre, the taxi's
    own cell included), drawn with probability proportional to its recent request count ``density[cell]``;
    ``-1`` when no cell nearby saw a request (or the drawn hub cannot be reached)."""
    here = dm.hub_of_cell[int(dm.node_cell[node])]
    d2 = (dm.center_x_m - dm.center_x_m[here]) ** 2 + (dm.center_y_m - dm.center_y_m[here]) ** 2
    near = np.flatnonzero(d2 <= radius_m**2)
    w = density[dm.cells[near]]
    total = float(w.sum())
    if total <= 0.0:
        return -1
    pick = int(near[int(np.searchsorted(np.cumsum(w), rng.random() * total, side="right"))])
    if not np.isfinite(dm.time_to[pick, node]):
        return -1
    return pick


def drift_walk(dm: DriftMap, hub_row: int, node: int, budget_s: float) -> tuple[int, float]:
    """Follow the tree toward hub ``hub_row`` from ``node`` for at most ``budget_s`` seconds of travel.

    Returns the node reached (the taxi stops at the last node it can reach in time) and the time used.
    """
    toward, time_to = dm.toward[hub_row], dm.time_to[hub_row]
    used = 0.0
    while True:
        nxt = int(toward[node])
        if nxt < 0:
            return node, used
        step = float(time_to[node] - time_to[nxt])
        if used + step > budget_s:
            return node, used
        used += step
        node = nxt
