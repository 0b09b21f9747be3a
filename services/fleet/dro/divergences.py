"""The seven φ-divergences of the paper's Appendix A (Table A.1), as docs/METHOD.md section 8 fixes them.

Each :class:`Divergence` carries φ, its convex conjugate φ*, the curvature φ''(1) that scales the radius,
the slope at infinity ``L = lim φ(t)/t`` (finite exactly when mass may "pop" to cells the data left empty),
and φ(0) (finite exactly when the data's cells may be "suppressed" to zero mass).

The divergence of ``p`` from ``q`` (Eq. (20) of the paper, ``I_φ(p, q) = Σ_j q_j φ(p_j / q_j)``) uses the
usual conventions for empty cells: ``0 · φ(p / 0) = p · L`` (infinite when ``L`` is and ``p > 0``), and 0
when ``p = 0``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import wrightomega, xlog1py, xlogy

__all__ = [
    "DIVERGENCE_NAMES",
    "DIVERGENCES",
    "Divergence",
    "get_divergence",
    "divergence_value",
    "j_inverse_derivative",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Divergence:
    """One φ-divergence: φ, φ*, φ''(1), ``L = lim φ(t)/t``, φ(0), popping and suppression.

    Attributes
    ----------
    name, title
        Short name (``"kl"``) and the paper's name (``"Kullback-Leibler"``).
    phi
        φ(t) for ``t >= 0`` (``inf`` where φ is infinite, e.g. Burg at 0).
    phi_1p
        ``u -> φ(1 + u)`` for ``u >= -1``, written without cancellation near ``u = 0`` (where φ is O(u²)).
    conjugate
        φ*(s) = sup_{t >= 0} (s t - φ(t)); ``inf`` outside its domain.
    curvature
        φ''(1); ``None`` for the variation distance, which is not twice differentiable at 1.
    slope_at_infinity
        ``L = lim_{t -> inf} φ(t) / t``: the cost of a unit of mass put on an empty cell (``inf``: none may).
    phi_at_zero
        φ(0): the cost per unit of ``q`` of a cell whose mass is removed entirely (``inf``: never removed).
    """

    name: str
    title: str
    phi: Callable[[FloatArray], FloatArray]
    phi_1p: Callable[[FloatArray], FloatArray]
    conjugate: Callable[[FloatArray], FloatArray]
    curvature: float | None
    slope_at_infinity: float
    phi_at_zero: float

    @property
    def popping(self) -> bool:
        """Whether mass can move to cells with ``q_j = 0`` (``L`` finite)."""
        return bool(np.isfinite(self.slope_at_infinity))

    @property
    def suppression(self) -> bool:
        """Whether a cell with ``q_j > 0`` can lose all its mass (φ(0) finite)."""
        return bool(np.isfinite(self.phi_at_zero))


def _kl(t: FloatArray) -> FloatArray:
    return np.asarray(xlogy(t, t) - t + 1.0, dtype=np.float64)


def _kl_1p(u: FloatArray) -> FloatArray:
    return np.asarray(xlog1py(1.0 + u, u) - u, dtype=np.float64)


def _kl_star(s: FloatArray) -> FloatArray:
    with np.errstate(over="ignore"):
        return np.expm1(s)


def _burg(t: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore"):
        return np.where(t > 0, -np.log(np.where(t > 0, t, 1.0)) + t - 1.0, np.inf)


def _burg_1p(u: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore"):
        return np.where(u > -1.0, u - np.log1p(np.maximum(u, -1.0)), np.inf)


def _burg_star(s: FloatArray) -> FloatArray:
    return np.where(s < 1.0, -np.log1p(-np.where(s < 1.0, s, 0.0)), np.inf)


def _j(t: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore"):
        return np.where(t > 0, (t - 1.0) * np.log(np.where(t > 0, t, 1.0)), np.inf)


def _j_1p(u: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore"):
        return np.where(u > -1.0, u * np.log1p(np.maximum(u, -1.0)), np.inf)


def _chi2(t: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore"):
        return np.where(t > 0, (t - 1.0) ** 2 / np.where(t > 0, t, 1.0), np.inf)


def _chi2_1p(u: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore"):
        return np.where(u > -1.0, u * u / np.where(u > -1.0, 1.0 + u, 1.0), np.inf)


def _chi2_star(s: FloatArray) -> FloatArray:
    return np.where(s <= 1.0, 2.0 - 2.0 * np.sqrt(np.maximum(1.0 - s, 0.0)), np.inf)


def _mchi2(t: FloatArray) -> FloatArray:
    return (t - 1.0) ** 2


def _mchi2_1p(u: FloatArray) -> FloatArray:
    return u * u


def _mchi2_star(s: FloatArray) -> FloatArray:
    return np.where(s >= -2.0, s + s * s / 4.0, -1.0)


def _hellinger(t: FloatArray) -> FloatArray:
    return (np.sqrt(t) - 1.0) ** 2


def _hellinger_1p(u: FloatArray) -> FloatArray:
    return (u / (np.sqrt(1.0 + u) + 1.0)) ** 2


def _hellinger_star(s: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore"):
        return np.where(s < 1.0, s / np.where(s < 1.0, 1.0 - s, 1.0), np.inf)


def _variation(t: FloatArray) -> FloatArray:
    return np.abs(t - 1.0)


def _variation_1p(u: FloatArray) -> FloatArray:
    return np.abs(u)


def _variation_star(s: FloatArray) -> FloatArray:
    return np.where(s <= 1.0, np.maximum(s, -1.0), np.inf)


def j_inverse_derivative(y: ArrayLike) -> FloatArray:
    """``log t`` with ``φ_J'(t) = log t + 1 - 1/t = y`` (the J-divergence has no closed-form conjugate).

    With ``z = 1/t`` the equation reads ``z + log z = 1 - y``, so ``z = ω(1 - y)``, Wright's omega function
    (``scipy.special.wrightomega``, no overflow for any ``y``). ``log t = -log ω(1 - y)`` for ``y <= 1`` and
    ``y - 1 + ω(1 - y)`` above (same value, no cancellation on either side).
    """
    yv = np.asarray(y, dtype=np.float64)
    w = wrightomega(1.0 - yv)
    with np.errstate(divide="ignore"):  # ω underflows to 0 far above 1, where the other branch is used
        return np.asarray(np.where(yv > 1.0, yv - 1.0 + w, -np.log(w)), dtype=np.float64)


def _j_star(s: FloatArray) -> FloatArray:
    # φ*(s) = s t - φ(t) at φ'(t) = s
    x = j_inverse_derivative(s)
    with np.errstate(over="ignore", invalid="ignore"):
        t = np.exp(x)
        return np.asarray(np.where(np.isinf(t), np.inf, s * t - (t - 1.0) * x), dtype=np.float64)


_TABLE = (
    Divergence("kl", "Kullback-Leibler", _kl, _kl_1p, _kl_star, 1.0, np.inf, 1.0),
    Divergence("burg", "Burg entropy", _burg, _burg_1p, _burg_star, 1.0, 1.0, np.inf),
    Divergence("j", "J-divergence", _j, _j_1p, _j_star, 2.0, np.inf, np.inf),
    Divergence("chi2", "chi-squared", _chi2, _chi2_1p, _chi2_star, 2.0, 1.0, np.inf),
    Divergence("modified_chi2", "modified chi-squared", _mchi2, _mchi2_1p, _mchi2_star, 2.0, np.inf, 1.0),
    Divergence("hellinger", "Hellinger distance", _hellinger, _hellinger_1p, _hellinger_star, 0.5, 1.0, 1.0),
    Divergence("variation", "variation distance", _variation, _variation_1p, _variation_star, None, 1.0, 1.0),
)

DIVERGENCES: Mapping[str, Divergence] = MappingProxyType({d.name: d for d in _TABLE})
"""The seven divergences by name, in the paper's order."""

DIVERGENCE_NAMES: tuple[str, ...] = tuple(d.name for d in _TABLE)


def get_divergence(name: str | Divergence) -> Divergence:
    """The divergence called ``name`` (a :class:`Divergence` is returned as is); ``ValueError`` if unknown."""
    if isinstance(name, Divergence):
        return name
    try:
        return DIVERGENCES[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown divergence {name!r}; expected one of {', '.join(DIVERGENCE_NAMES)}"
        ) from None


def divergence_value(p: ArrayLike, q: ArrayLike, divergence: str | Divergence) -> float:
    """``I_φ(p, q) = Σ_j q_j φ(p_j / q_j)`` (Eq. (20)); an empty cell (``q_j = 0``) costs ``p_j · L``.

    Near ``p_j = q_j`` a term is evaluated as ``q_j φ(1 + u_j)`` with ``u_j = (p_j - q_j) / q_j`` (accurate
    for tiny divergences), elsewhere from ``t_j = p_j / q_j`` (accurate for tiny ``p_j``).
    """
    div = get_divergence(divergence)
    pv = np.asarray(p, dtype=np.float64)
    qv = np.asarray(q, dtype=np.float64)
    if pv.shape != qv.shape:
        raise ValueError(f"p and q differ in shape: {pv.shape} vs {qv.shape}")
    full = qv > 0
    t = pv[full] / qv[full]
    near = np.abs(t - 1.0) < 0.5
    terms = np.where(near, div.phi_1p(np.where(near, (pv[full] - qv[full]) / qv[full], 0.0)), div.phi(t))
    total = float(np.dot(qv[full], terms))
    popped = pv[~full]
    if np.any(popped > 0):
        total += float(np.sum(popped)) * div.slope_at_infinity
    return total
