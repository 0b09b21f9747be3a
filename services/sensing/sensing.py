"""Sensing utility: Theta, the marginal gain of a path, timed G-routes and Gamma (docs/METHOD.md section 3).

A path is evaluated against the counts at the start of the epoch: a (cell, interval) pair adds
``mu_t * s_g * ((L + 1)**rho - L**rho)`` the first time the path enters it, unless the taxi is already
counted there. ``t`` is the interval in which the taxi *enters* the cell (departure + travel time).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from services.model import IntervalKey

if TYPE_CHECKING:
    from services.city import City

__all__ = [
    "theta",
    "theta_gain",
    "TimedCells",
    "timed_cells",
    "gamma",
    "coverage_rate",
]


def theta(count: NDArray[np.int64] | int, rho: float) -> NDArray[np.float64] | float:
    """Theta(Lambda) = Lambda**rho (Eq. 2); Theta(0) = 0."""
    out: NDArray[np.float64] | float = np.power(count, rho)
    return out


def theta_gain(
    count: NDArray[np.float64] | float, added: NDArray[np.float64] | float, rho: float
) -> NDArray[np.float64]:
    """Theta(Lambda + n) - Theta(Lambda): what ``n`` more distinct vehicles add to a (cell, interval).

    With ``n = 1`` and the weights mu_t s_g this is the summand of Eq. (3); every gain in the core is
    computed from it (the compiled kernels read it from ``gains.Gains``).
    """
    lam = np.asarray(count, dtype=np.float64)
    out: NDArray[np.float64] = np.power(lam + added, rho) - np.power(lam, rho)
    return out


@dataclass(frozen=True, slots=True)
class TimedCells:
    """A path's distinct (interval, cell) crossings in order of first entry, with entry times."""

    cells: NDArray[np.int64]  # cell index of each entry
    intervals: NDArray[np.int64]  # interval key of each entry
    entry_s: NDArray[np.float64]  # POSIX time of each entry

    def pairs(self) -> list[tuple[IntervalKey, int]]:
        return [(IntervalKey(int(k)), int(c)) for k, c in zip(self.intervals, self.cells, strict=True)]


def timed_cells(city: City, edge_ids: NDArray[np.int64], depart_s: float) -> TimedCells:
    """Timed G-route of the path made of ``edge_ids`` leaving at ``depart_s``.

    Every crossing of every edge is timed (edge start time + fraction x edge travel time); a (cell,
    interval) pair entered twice is kept once, at its first entry ("a cell crossed twice in one interval
    counts once").
    """
    ec = city.edge_cells
    t_edge = city.network.edge_time_s[edge_ids]
    start = depart_s + np.concatenate(([0.0], np.cumsum(t_edge)[:-1])) if len(edge_ids) else np.zeros(0)
    lo = ec.ptr[edge_ids]
    hi = ec.ptr[edge_ids + 1]
    n = hi - lo
    if n.sum() == 0:
        empty = np.zeros(0, dtype=np.int64)
        return TimedCells(empty, empty.copy(), np.zeros(0))
    rep = np.repeat(np.arange(len(edge_ids)), n)
    flat = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)])
    cells = ec.cell[flat].astype(np.int64)
    entry = start[rep] + ec.frac[flat] * t_edge[rep]
    intervals = city.horizon.intervals_of(entry)
    key = intervals * city.grid.n_cells + cells
    _, first = np.unique(key, return_index=True)
    first.sort()
    return TimedCells(cells[first], intervals[first], entry[first])


def gamma(city: City, counts: Mapping[IntervalKey, NDArray[np.int64]], intervals: Iterable[int]) -> float:
    """Gamma = sum_t mu_t sum_g s_g Lambda_{g,t}^rho (Eq. 1) over ``intervals``."""
    total = 0.0
    for k in intervals:
        arr = counts.get(IntervalKey(int(k)))
        if arr is None:
            continue
        total += city.mu(int(k)) * float(
            np.dot(city.cell_weight, theta(arr.astype(np.float64), city.params.rho))
        )
    return total


def coverage_rate(city: City, count: NDArray[np.int64]) -> float:
    """Share of the cells the network touches with Lambda >= 1 in one interval."""
    touched = city.cell_weight > 0
    n = int(touched.sum())
    return float(((count > 0) & touched).sum()) / n if n else 0.0
