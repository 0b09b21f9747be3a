"""The cells of the empirical distribution: equal-width bins (the default) or one cell per sample.

docs/METHOD.md section 8: the default support is ``w`` equal-width bins over ``[min f, max f]`` (never
extended beyond the data), each non-empty bin represented by the mean of its samples, an empty bin by its
midpoint, ``q_j = count_j / M`` and ``m = w``. With one cell per sample ``m = M``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from services.fleet.dro.inputs import DroInputError, as_samples

__all__ = ["SupportKind", "SUPPORT_KINDS", "Support", "binned_support", "sample_support", "make_support"]

SupportKind = Literal["binned", "samples"]
SUPPORT_KINDS: tuple[SupportKind, ...] = ("binned", "samples")
MAX_BINS = 10_000


@dataclass(frozen=True, slots=True)
class Support:
    """Cells with their representative values and empirical probabilities.

    Attributes
    ----------
    kind
        ``"binned"`` or ``"samples"``.
    values
        Representative value of each cell, ascending: bin means (midpoints for empty bins), or the sorted
        samples.
    q
        Empirical probability of each cell, ``count / M`` (zero for empty bins).
    counts
        Samples per cell.
    edges
        Bin edges (``w + 1`` of them) for ``"binned"``; ``None`` for ``"samples"``.
    midpoints
        Bin midpoints ``g_i = L + (i - 1/2) Δ`` (the paper's grid, used by the box LP); ``None`` for samples.
    n_samples
        ``M``.
    nominal_cells
        The ``m`` of the radius rule: ``w`` for bins, ``M`` for samples (also when the data are degenerate).
    degenerate
        Every sample is equal: the support is that one value (``values`` has one entry).
    """

    kind: SupportKind
    values: NDArray[np.float64]
    q: NDArray[np.float64]
    counts: NDArray[np.int64]
    edges: NDArray[np.float64] | None
    midpoints: NDArray[np.float64] | None
    n_samples: int
    nominal_cells: int
    degenerate: bool

    @property
    def m(self) -> int:
        """Number of cells."""
        return int(self.values.size)


def _check_bins(bins: int) -> int:
    if isinstance(bins, bool) or not isinstance(bins, int | np.integer):
        raise DroInputError("bins", f"must be an integer, got {bins!r}")
    if not 2 <= int(bins) <= MAX_BINS:
        raise DroInputError("bins", f"must lie in 2..{MAX_BINS}, got {bins}")
    return int(bins)


def binned_support(samples: ArrayLike, bins: int = 10) -> Support:
    """``bins`` equal-width bins over ``[min, max]`` of the samples; a bin's value is its samples' mean.

    A sample on an inner edge belongs to the bin above it, the maximum to the last bin. When every sample is
    equal there is no range to divide: the support is the single value with ``q = [1]`` and
    ``degenerate=True`` (``nominal_cells`` stays ``bins``, so the radius rule is unchanged).
    """
    w = _check_bins(bins)
    x = as_samples(samples)
    n = int(x.size)
    lo, hi = float(x.min()), float(x.max())
    if lo == hi:
        one, count = np.array([lo]), np.array([n], dtype=np.int64)
        return Support("binned", one, np.ones(1), count, np.array([lo, hi]), one.copy(), n, w, True)
    edges = np.linspace(lo, hi, w + 1)
    edges[0], edges[-1] = lo, hi
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, w - 1)
    counts = np.bincount(idx, minlength=w).astype(np.int64)
    sums = np.bincount(idx, weights=x, minlength=w)
    midpoints = 0.5 * (edges[:-1] + edges[1:])
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, sums / np.maximum(counts, 1), midpoints)
    # a bin's mean lies in its bin; clip the rounding of the division
    means = np.clip(means, edges[:-1], edges[1:])
    return Support("binned", means, counts / n, counts, edges, midpoints, n, w, False)


def sample_support(samples: ArrayLike) -> Support:
    """One cell per sample (``m = M``, ``q_j = 1/M``), sorted ascending.

    Repeated values stay separate cells, so ``m = M`` as the radius rule expects; the solvers merge equal
    values internally, which does not change the worst case (the optimal ``p`` is proportional to ``q`` over
    cells of equal value). ``degenerate`` is set when every sample is equal.
    """
    x = np.sort(as_samples(samples))
    n = int(x.size)
    return Support(
        "samples", x, np.full(n, 1.0 / n), np.ones(n, dtype=np.int64), None, None, n, n, bool(x[0] == x[-1])
    )


def make_support(samples: ArrayLike, kind: str = "binned", bins: int = 10) -> Support:
    """The support of the given ``kind`` (``"binned"`` with ``bins`` bins, or ``"samples"``)."""
    if kind == "binned":
        return binned_support(samples, bins)
    if kind == "samples":
        return sample_support(samples)
    raise DroInputError("support", f"unknown support {kind!r}; expected one of {', '.join(SUPPORT_KINDS)}")
