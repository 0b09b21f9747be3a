"""The sensing model (paper Section 3.1, docs/METHOD.md section 3): the grid of cells a taxi senses, the
counts Λ, the weights Θ and the marginal gain ϑ of a path.

* ``grid``: :class:`Grid` and the cells every edge crosses (:class:`EdgeCells`).
* ``sensing``: Θ, ϑ, G-routes with their entry times, Γ and the coverage rate.
* ``gains``: gain tables (float and exact fixed point), per-taxi counted pairs, and the compiled evaluation of
  a path, a tree and many pairs (``eval_path``, ``eval_tree``, ``eval_pairs``).
"""

from services.sensing.gains import (
    Counted,
    Gains,
    TreeOut,
    TreeScratch,
    counted_csr,
    counted_rows,
    distinct_cells,
    eval_pairs,
    eval_path,
    eval_tree,
    fixed_point_unit,
    gain_table,
    mark,
    pair_gains_q,
    path_facts,
    timed_pairs,
    tree_scratch,
)
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
from services.sensing.sensing import TimedCells, coverage_rate, gamma, theta, theta_gain, timed_cells

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
    "theta",
    "theta_gain",
    "TimedCells",
    "timed_cells",
    "gamma",
    "coverage_rate",
    "Gains",
    "gain_table",
    "Counted",
    "counted_csr",
    "counted_rows",
    "mark",
    "eval_path",
    "eval_tree",
    "TreeScratch",
    "TreeOut",
    "tree_scratch",
    "eval_pairs",
    "pair_gains_q",
    "distinct_cells",
    "path_facts",
    "timed_pairs",
    "fixed_point_unit",
]
