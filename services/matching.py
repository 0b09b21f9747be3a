"""Exact lexicographic bipartite matchings for the three steps (Eq. 4-11, 13-16; METHOD section 4).

Each step has a primary objective and a tie-break. Both are encoded in *integer* weights so one
assignment solve is exact: ``W = primary * K + secondary`` with ``K`` larger than any possible total of the
secondary, and every weight and partial sum kept below 2**53 so float64 arithmetic inside
``scipy.optimize.linear_sum_assignment`` is exact integer arithmetic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

__all__ = ["EXACT_LIMIT", "Assignment", "max_weight_matching", "lexicographic_weights", "quantize"]

EXACT_LIMIT = 2**50
"""Bound on the largest possible total weight of a matching (headroom below 2**53 for partial sums)."""


@dataclass(frozen=True, slots=True)
class Assignment:
    """Matched (row, col) pairs with their integer weights; ``total`` is their sum."""

    rows: NDArray[np.int64]
    cols: NDArray[np.int64]
    total: int


def max_weight_matching(weight: NDArray[np.int64]) -> Assignment:
    """Maximum-weight matching (each row and column at most once) over pairs with ``weight > 0``.

    Pairs with ``weight <= 0`` are never matched (non-positive means infeasible or not worth it).
    Exact for integer weights whose possible total stays below ``EXACT_LIMIT``.
    """
    n, m = weight.shape
    if n == 0 or m == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Assignment(empty, empty.copy(), 0)
    w = np.where(weight > 0, weight, 0).astype(np.int64)
    bound = int(w.max()) * min(n, m)
    if bound >= EXACT_LIMIT:
        raise ValueError(f"weights too large for an exact solve: bound {bound} >= 2**50")
    rows, cols = linear_sum_assignment(w.astype(np.float64), maximize=True)
    keep = w[rows, cols] > 0
    rows = rows[keep].astype(np.int64)
    cols = cols[keep].astype(np.int64)
    return Assignment(rows, cols, int(w[rows, cols].sum()))


def quantize(values: NDArray[np.float64], unit: float) -> NDArray[np.int64]:
    """Round non-negative ``values`` to integer multiples of ``unit``."""
    return np.rint(np.asarray(values, dtype=np.float64) / unit).astype(np.int64)


def lexicographic_weights(
    feasible: NDArray[np.bool_],
    primary: NDArray[np.int64],
    secondary: NDArray[np.int64],
    *,
    secondary_sense: str,
) -> NDArray[np.int64]:
    """Integer weights for "maximize sum(primary), then optimize sum(secondary)".

    ``primary`` and ``secondary`` are non-negative integers. With ``secondary_sense="min"`` a pair's weight
    is ``primary*K - secondary``; with ``"max"`` it is ``primary*K + secondary``; ``K`` exceeds the largest
    total of ``secondary`` over any matching, so no secondary saving can buy a primary loss. Infeasible pairs
    get weight 0 (never matched); with ``"min"`` a pair whose primary is 0 also gets a non-positive weight:
    adding it would only add to the secondary, so it is left out, as the lexicographic objective demands.
    """
    n, m = feasible.shape
    if n == 0 or m == 0:
        return np.zeros((n, m), dtype=np.int64)
    sec = np.where(feasible, secondary, 0).astype(np.int64)
    k = int(sec.max(initial=0)) * min(n, m) + 1
    if secondary_sense == "min":
        w = primary.astype(np.int64) * k - sec
    elif secondary_sense == "max":
        w = primary.astype(np.int64) * k + sec
    else:
        raise ValueError("secondary_sense must be 'min' or 'max'")
    return np.where(feasible, w, 0)
