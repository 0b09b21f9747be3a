"""The 1 km sensing grid G and the cells each edge crosses (METHOD section 2).

Implementation owner: the cities work (see docs/DESIGN.md). Field names here are the contract.

Definitions (exact, so tests and clients can reproduce them):

* cell of a point (x, y): ``col = floor((x - origin_x_m) / cell_m)``, ``row = floor((y - origin_y_m) / cell_m)``;
  cell index ``row * n_cols + col``. Rows grow northward.
* the cells an edge crosses: split the straight segment from its tail node to its head node at every grid
  line it meets (parameters ``s`` in ``[0, 1]``); every piece of positive length lies in one cell (its
  midpoint's cell). The edge crosses those cells, in order, each listed once per maximal run, with the
  fraction ``s`` where the piece starts (``frac``; 0 for the first). A zero-length edge crosses its tail's cell.
* the G-route of a path: the ordered list of distinct cells its edges cross (first entry order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Grid", "EdgeCells"]


@dataclass(frozen=True, slots=True)
class Grid:
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
