"""The 1 km sensing grid G and the cells each edge crosses (docs/METHOD.md section 2).

Field names here are the contract the city, the gains and the GeoJSON documents share.

Definitions (exact, so tests and clients can reproduce them):

* cell of a point (x, y): ``col = floor((x - origin_x_m) / cell_m)``,
  ``row = floor((y - origin_y_m) / cell_m)``; cell index ``row * n_cols + col``. Rows grow northward.
* the cells an edge crosses: split the straight segment from its tail node to its head node at every grid
  line it meets (parameters ``s`` in ``[0, 1]``); every piece of positive length lies in one cell (its
  midpoint's cell). The edge crosses those cells, in order, each listed once per maximal run, with the
  fraction ``s`` where the piece starts (``frac``; 0 for the first). A zero-length edge crosses its tail's
  cell.
* the G-route of a path: the ordered list of distinct cells its edges cross (first entry order).

"Positive length" is taken as longer than ``1e-9`` metres so that floating-point noise where a segment
passes through a grid corner does not create slivers in the diagonal neighbours.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from services.network.network import Network

__all__ = [
    "Grid",
    "EdgeCells",
    "build_grid",
    "cells_of_points",
    "node_col_row",
    "segment_cells",
    "build_edge_cells",
    "touched_cells",
    "path_cells",
]

_MIN_PIECE_M = 1e-9


@dataclass(frozen=True, slots=True)
class Grid:
    """A square grid in a network's projected plane (see the module docstring for the cell rules).

    Attributes
    ----------
    crs : str               projection of the coordinates (the network's)
    origin_x_m, origin_y_m : float  lower-left corner, multiples of ``cell_m``
    cell_m : float          side of a cell in metres
    n_cols, n_rows : int    cells are ``row * n_cols + col``, rows growing northward
    """

    crs: str
    origin_x_m: float  # lower-left corner, a multiple of cell_m
    origin_y_m: float
    cell_m: float
    n_cols: int
    n_rows: int

    @property
    def n_cells(self) -> int:
        return self.n_cols * self.n_rows

    def col_row(self, cell: int) -> tuple[int, int]:
        return cell % self.n_cols, cell // self.n_cols


@dataclass(frozen=True, slots=True)
class EdgeCells:
    """Cells crossed by every edge, CSR by edge: edge e crosses ``cell[ptr[e]:ptr[e+1]]`` in order,
    entering each at fraction ``frac[...]`` of the edge (the first at 0)."""

    ptr: NDArray[np.int64]
    cell: NDArray[np.int32]
    frac: NDArray[np.float64]


def build_grid(network: Network, cell_m: float = 1000.0) -> Grid:
    """The grid of ``cell_m`` squares covering every node of a network.

    Parameters
    ----------
    network : Network
    cell_m : float
        Side of a cell in projected metres (1 km in the paper).

    Returns
    -------
    Grid
        ``origin = floor(min / cell_m) * cell_m`` on both axes; just enough columns and rows that every
        node's cell (by the point rule, so a node on the last line opens one more column) is inside.
    """
    if not (np.isfinite(cell_m) and cell_m > 0):
        raise ValueError("cell_m must be positive")
    if network.n_nodes == 0:
        raise ValueError("the network has no nodes")
    ox = float(np.floor(network.x_m.min() / cell_m) * cell_m)
    oy = float(np.floor(network.y_m.min() / cell_m) * cell_m)
    n_cols = int(np.floor((network.x_m.max() - ox) / cell_m)) + 1
    n_rows = int(np.floor((network.y_m.max() - oy) / cell_m)) + 1
    return Grid(
        crs=network.crs, origin_x_m=ox, origin_y_m=oy, cell_m=float(cell_m), n_cols=n_cols, n_rows=n_rows
    )


def _col_row(
    grid: Grid, x: NDArray[np.float64], y: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    col = np.floor((x - grid.origin_x_m) / grid.cell_m).astype(np.int64)
    row = np.floor((y - grid.origin_y_m) / grid.cell_m).astype(np.int64)
    return col, row


def cells_of_points(grid: Grid, x: ArrayLike, y: ArrayLike) -> NDArray[np.int64]:
    """Cell index of each point ``(x, y)`` (projected metres).

    Raises
    ------
    ValueError
        If a point is not finite or lies outside the grid.
    """
    xa = np.atleast_1d(np.asarray(x, dtype=np.float64))
    ya = np.atleast_1d(np.asarray(y, dtype=np.float64))
    if xa.shape != ya.shape:
        raise ValueError("x and y must have the same shape")
    if not (np.isfinite(xa).all() and np.isfinite(ya).all()):
        raise ValueError("points must be finite")
    col, row = _col_row(grid, xa, ya)
    outside = (col < 0) | (col >= grid.n_cols) | (row < 0) | (row >= grid.n_rows)
    if outside.any():
        i = int(np.flatnonzero(outside.ravel())[0])
        raise ValueError(f"point ({xa.ravel()[i]:.1f}, {ya.ravel()[i]:.1f}) lies outside the grid")
    return row * grid.n_cols + col


def node_col_row(grid: Grid, network: Network) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Column and row of every node's cell by the point rule (the module docstring), in node order.

    Parameters
    ----------
    grid : Grid
        A grid covering the network (``build_grid``), so every column and row is inside it.
    network : Network

    Returns
    -------
    col, row : int64 (n_nodes,)
        The cell of node ``i`` is ``row[i] * grid.n_cols + col[i]``.
    """
    return _col_row(grid, network.x_m, network.y_m)


def _crossings(
    grid: Grid,
    x0: NDArray[np.float64],
    y0: NDArray[np.float64],
    x1: NDArray[np.float64],
    y1: NDArray[np.float64],
) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.float64]]:
    """Vectorized core of the edge rule for segments ``i`` from ``(x0[i], y0[i])`` to ``(x1[i], y1[i])``.

    Returns ``ptr, cell, frac`` in the layout of :class:`EdgeCells`.
    """
    k = x0.size
    seg = np.arange(k, dtype=np.int64)
    length = np.hypot(x1 - x0, y1 - y0)

    # every grid line strictly between the end coordinates on each axis; lines k for floor(a)<k<=floor(b)
    def lines(
        a0: NDArray[np.float64], a1: NDArray[np.float64]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        c0 = np.floor(a0).astype(np.int64)
        c1 = np.floor(a1).astype(np.int64)
        lo = np.minimum(c0, c1)
        cnt = np.abs(c1 - c0)
        total = int(cnt.sum())
        owner = np.repeat(seg, cnt)
        start = np.repeat(np.cumsum(cnt) - cnt, cnt)
        line = np.repeat(lo + 1, cnt) + (np.arange(total, dtype=np.int64) - start)
        a0o, a1o = a0[owner], a1[owner]
        s = (line - a0o) / (a1o - a0o)  # cnt > 0 implies a1 != a0
        return owner, s

    ux0 = (x0 - grid.origin_x_m) / grid.cell_m
    ux1 = (x1 - grid.origin_x_m) / grid.cell_m
    uy0 = (y0 - grid.origin_y_m) / grid.cell_m
    uy1 = (y1 - grid.origin_y_m) / grid.cell_m
    ov, sv = lines(ux0, ux1)
    oh, sh = lines(uy0, uy1)
    owner = np.concatenate([seg, seg, ov, oh])
    s = np.clip(np.concatenate([np.zeros(k), np.ones(k), sv, sh]), 0.0, 1.0)
    order = np.lexsort((s, owner))
    owner, s = owner[order], s[order]

    # pieces between consecutive breakpoints of the same segment
    same = owner[1:] == owner[:-1]
    pe = owner[:-1][same]
    sa = s[:-1][same]
    sb = s[1:][same]
    keep = (sb - sa) * length[pe] > _MIN_PIECE_M
    pe, sa, sb = pe[keep], sa[keep], sb[keep]
    mid = 0.5 * (sa + sb)
    col, row = _col_row(grid, x0[pe] + mid * (x1[pe] - x0[pe]), y0[pe] + mid * (y1[pe] - y0[pe]))
    col = np.clip(col, 0, grid.n_cols - 1)
    row = np.clip(row, 0, grid.n_rows - 1)
    cell = row * grid.n_cols + col

    # one entry per maximal run of the same cell, starting at the run's first piece
    new_run = np.ones(pe.size, dtype=bool)
    new_run[1:] = (pe[1:] != pe[:-1]) | (cell[1:] != cell[:-1])
    pe, cell, frac = pe[new_run], cell[new_run], sa[new_run]

    # segments without a piece (zero length) cross their tail's cell
    empty = np.ones(k, dtype=bool)
    empty[pe] = False
    if empty.any():
        ec, er = _col_row(grid, x0[empty], y0[empty])
        ecell = np.clip(er, 0, grid.n_rows - 1) * grid.n_cols + np.clip(ec, 0, grid.n_cols - 1)
        pe = np.concatenate([pe, seg[empty]])
        cell = np.concatenate([cell, ecell])
        frac = np.concatenate([frac, np.zeros(int(empty.sum()))])
        order = np.lexsort((frac, pe))
        pe, cell, frac = pe[order], cell[order], frac[order]
    # the first run starts at 0 (s of its first piece is 0 unless the segment begins with a sliver)
    first = np.ones(pe.size, dtype=bool)
    first[1:] = pe[1:] != pe[:-1]
    frac[first] = 0.0

    ptr = np.zeros(k + 1, dtype=np.int64)
    np.cumsum(np.bincount(pe, minlength=k), out=ptr[1:])
    return ptr, cell.astype(np.int32), frac.astype(np.float64)


def segment_cells(
    grid: Grid, x0: float, y0: float, x1: float, y1: float
) -> tuple[NDArray[np.int32], NDArray[np.float64]]:
    """The cells a straight segment crosses, in order, and where it enters each (module docstring rule).

    Parameters
    ----------
    grid : Grid
    x0, y0, x1, y1 : float
        Tail and head in projected metres.

    Returns
    -------
    cells : int32 (r,)
        One entry per maximal run of pieces in the same cell.
    fracs : float64 (r,)
        Segment parameter where each run starts (first = 0).
    """
    pts = [np.array([float(c)]) for c in (x0, y0, x1, y1)]
    if not all(np.isfinite(p).all() for p in pts):
        raise ValueError("segment end points must be finite")
    _, cell, frac = _crossings(grid, *pts)
    return cell, frac


def build_edge_cells(grid: Grid, network: Network) -> EdgeCells:
    """The cells every edge of a network crosses (vectorized over all edges).

    Returns
    -------
    EdgeCells
        CSR by edge, in the network's edge order.
    """
    u = network.edge_u
    v = network.edge_v
    ptr, cell, frac = _crossings(grid, network.x_m[u], network.y_m[u], network.x_m[v], network.y_m[v])
    return EdgeCells(ptr=ptr, cell=cell, frac=frac)


def touched_cells(grid: Grid, network: Network, edge_cells: EdgeCells) -> NDArray[np.int64]:
    """Sorted unique cells that contain a node or are crossed by an edge."""
    node_cells = cells_of_points(grid, network.x_m, network.y_m)
    return np.unique(np.concatenate([node_cells, edge_cells.cell.astype(np.int64)]))


def path_cells(edge_cells: EdgeCells, edge_ids: ArrayLike | Sequence[int]) -> list[int]:
    """G-route of a path given by its edges: distinct cells crossed, in order of first entry.

    Parameters
    ----------
    edge_cells : EdgeCells
    edge_ids : int array
        The path's edges in order (e.g. from :meth:`Network.edge_ids`).

    Returns
    -------
    list of int
    """
    e = np.asarray(edge_ids, dtype=np.int64).ravel()
    if e.size == 0:
        return []
    starts = edge_cells.ptr[e]
    counts = edge_cells.ptr[e + 1] - starts
    offs = np.arange(int(counts.sum()), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    cells = edge_cells.cell[np.repeat(starts, counts) + offs]
    uniq, first = np.unique(cells, return_index=True)
    return [int(c) for c in uniq[np.argsort(first)]]
