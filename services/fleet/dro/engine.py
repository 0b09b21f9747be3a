"""From KPI samples to a worst-case expectation: support, radius, solve (docs/METHOD.md section 8)."""

from __future__ import annotations

from numpy.typing import ArrayLike

from services.fleet.dro.box_lp import solve_box_lp
from services.fleet.dro.divergences import DIVERGENCE_NAMES, DIVERGENCES, Divergence
from services.fleet.dro.exact import solve_exact
from services.fleet.dro.inputs import DroInputError, check_rho
from services.fleet.dro.radius import rho_from_alpha
from services.fleet.dro.result import METHODS, WorstCase
from services.fleet.dro.support import make_support

__all__ = ["DEFAULT_ALPHA", "worst_case"]

DEFAULT_ALPHA = 0.05


def worst_case(
    samples: ArrayLike,
    divergence: str | Divergence = "kl",
    *,
    alpha: float | None = None,
    rho: float | None = None,
    support: str = "binned",
    bins: int = 10,
    method: str = "exact",
) -> WorstCase:
    """The worst-case expected KPI over the φ-divergence ball around the samples' empirical distribution.

    Parameters
    ----------
    samples
        KPI samples ``f^1..f^M`` (``M >= 2``, finite).
    divergence
        One of ``kl`` (default), ``burg``, ``j``, ``chi2``, ``modified_chi2``, ``hellinger``, ``variation``.
    alpha, rho
        Either the significance level (default 0.05; ``ρ`` then follows Eq. (25) with ``m`` cells, see
        :func:`~services.fleet.dro.radius.rho_from_alpha`) or the radius itself; not both.
    support
        ``"binned"`` (default; ``bins`` equal-width bins over ``[min, max]``, bin means as values) or
        ``"samples"`` (one cell per sample, ``m = M``).
    bins
        ``w``, the number of bins (``>= 2``).
    method
        ``"exact"`` (default; :func:`~services.fleet.dro.exact.solve_exact` on the bin means) or
        ``"box_lp"`` (the paper's Eq. (28) on the bin midpoints, binned support only).

    Raises
    ------
    DroInputError
        A ``ValueError`` naming the offending parameter.
    """
    if isinstance(divergence, Divergence):
        div = divergence
    elif isinstance(divergence, str) and divergence in DIVERGENCES:
        div = DIVERGENCES[divergence]
    else:
        raise DroInputError(
            "divergence", f"unknown divergence {divergence!r}; expected one of {', '.join(DIVERGENCE_NAMES)}"
        )
    if method not in METHODS:
        raise DroInputError("method", f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if method == "box_lp" and support != "binned":
        raise DroInputError("method", "box_lp works on bins: use support='binned'")
    if alpha is not None and rho is not None:
        raise DroInputError("rho", "give alpha or rho, not both")
    cells = make_support(samples, support, bins)
    if rho is not None:
        radius = check_rho(rho)
    else:
        radius = rho_from_alpha(
            div, DEFAULT_ALPHA if alpha is None else alpha, cells.n_samples, cells.nominal_cells
        )
    if method == "box_lp":
        assert cells.midpoints is not None
        return solve_box_lp(cells.midpoints, cells.q, radius, div)
    return solve_exact(cells.values, cells.q, radius, div)
