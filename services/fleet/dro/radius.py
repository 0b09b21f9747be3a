"""The radius of the φ-divergence ball from a significance level (paper Eq. (25); docs/METHOD.md
section 8)."""

from __future__ import annotations

import math

from scipy.special import chdtri

from services.fleet.dro.divergences import Divergence, get_divergence
from services.fleet.dro.inputs import DroInputError, check_alpha

__all__ = ["rho_from_alpha"]


def rho_from_alpha(divergence: str | Divergence, alpha: float, n_samples: int, n_cells: int) -> float:
    """``ρ = φ''(1) / (2M) · χ²_{m-1, 1-α}`` (Eq. (25)); variation: ``ρ_V = sqrt(χ²_{m-1, 1-α} / M)``.

    Parameters
    ----------
    divergence
        Name or :class:`Divergence`.
    alpha
        Significance level, in (0, 1).
    n_samples
        ``M``, the number of samples behind the empirical distribution.
    n_cells
        ``m``, the number of cells (not samples): ``w`` for binned support.

    Notes
    -----
    The variation distance is not twice differentiable at 1; its radius is the one whose ball contains the
    modified-χ² confidence set (``Σ|p - q| <= sqrt(Σ (p - q)² / q)`` by Cauchy-Schwarz).
    """
    div = get_divergence(divergence)
    a = check_alpha(alpha)
    if isinstance(n_samples, bool) or int(n_samples) != n_samples or n_samples < 1:
        raise DroInputError("samples", f"the number of samples must be a positive integer, got {n_samples}")
    if isinstance(n_cells, bool) or int(n_cells) != n_cells or n_cells < 2:
        raise DroInputError("bins", f"the number of cells must be an integer >= 2, got {n_cells}")
    quantile = float(chdtri(int(n_cells) - 1, a))  # χ²_{m-1, 1-α}: the inverse survival function at α
    if div.curvature is None:
        return math.sqrt(quantile / int(n_samples))
    return div.curvature / (2.0 * int(n_samples)) * quantile
