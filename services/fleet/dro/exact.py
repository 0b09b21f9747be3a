"""The exact worst-case expectation over a φ-divergence ball, and its dual (docs/METHOD.md section 8).

:func:`solve_exact` reduces the problem (equal values merged, the one empty cell mass could usefully pop
to kept), normalizes the values, handles ``ρ = 0``, a single value and saturation, then calls the
divergence's solver in :mod:`services.fleet.dro.solvers` and maps the worst-case distribution back onto the
given cells. :func:`dual_objective` evaluates the convex dual, so a returned ``(η, λ)`` certifies the value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from services.fleet.dro.divergences import Divergence, divergence_value, get_divergence
from services.fleet.dro.inputs import DroInputError, check_rho
from services.fleet.dro.result import Status, WorstCase
from services.fleet.dro.solvers import SOLVERS, Reduced, ReducedSolution, Unbracketed

__all__ = ["check_problem", "solve_exact", "dual_objective"]

FloatArray = NDArray[np.float64]
_SLACK = 1e-12  # relative slack on the conjugate's domain when checking a certificate
_SATURATION_RTOL = 1e-12  # ρ within this of the saturation threshold counts as reaching it (rounding)


def check_problem(values: ArrayLike, q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Cell values and an empirical distribution over them: same length, finite, ``q >= 0``, ``Σ q = 1``.

    ``q`` is rescaled to sum to exactly one when it is off by at most ``1e-9``.
    """
    v = np.asarray(values, dtype=np.float64).copy()
    qv = np.asarray(q, dtype=np.float64).copy()
    if v.ndim != 1 or v.size < 1:
        raise DroInputError("values", f"must be a non-empty 1-D array, got shape {v.shape}")
    if qv.shape != v.shape:
        raise DroInputError("q", f"must have the shape of values {v.shape}, got {qv.shape}")
    if not np.all(np.isfinite(v)):
        raise DroInputError("values", "must be finite")
    if not np.all(np.isfinite(qv)) or np.any(qv < 0):
        raise DroInputError("q", "must be finite and non-negative")
    total = float(qv.sum())
    if abs(total - 1.0) > 1e-9:
        raise DroInputError("q", f"must sum to 1, sums to {total!r}")
    return v, qv / total


def _merged(v_full: FloatArray, q_full: FloatArray) -> tuple[FloatArray, NDArray[np.intp], FloatArray]:
    """The distinct values of the data cells (ascending), each cell's index among them and their merged
    probabilities."""
    if np.all(v_full[1:] > v_full[:-1]):  # distinct and ascending, as bins are: nothing to merge
        return v_full, np.arange(v_full.size), q_full
    uniq, inverse = np.unique(v_full, return_inverse=True)
    return uniq, inverse, np.bincount(inverse, weights=q_full).astype(np.float64)


def _popped(v: FloatArray, full: NDArray[np.bool_], uniq: FloatArray, div: Divergence) -> int | None:
    """The empty cell a popping divergence may put mass on: the highest, when it is above every data value."""
    if div.popping and not np.all(full):
        empty = np.flatnonzero(~full)
        k = int(empty[np.argmax(v[empty])])
        if v[k] > uniq[-1]:
            return k
    return None


@dataclass(frozen=True, slots=True)
class _Ball:
    """The checked problem with equal values merged: what the worst case can reach and where it starts."""

    div: Divergence
    v: FloatArray
    qv: FloatArray
    rho: float
    full: NDArray[np.bool_]  # the cells the data filled (q > 0)
    uniq: FloatArray  # their distinct values, ascending
    inverse: NDArray[np.intp]  # each filled cell's index in uniq
    group_q: FloatArray  # the merged probabilities of uniq
    pop: int | None  # the empty cell mass may pop to
    top: float  # the highest reachable value
    scale: float  # top minus the lowest data value
    mean: float  # Σ q f

    def worst_case(
        self, p: FloatArray, status: Status, value: float, eta: float, lam: float, note: str
    ) -> WorstCase:
        """The result with worst-case distribution ``p`` and certificate ``(η, λ)``."""
        i_p = divergence_value(p, self.qv, self.div)
        return WorstCase(
            value,
            self.mean,
            self.rho,
            int(self.v.size),
            self.v,
            self.qv,
            p,
            status,
            self.div.name,
            "exact",
            eta,
            lam,
            i_p,
            note,
        )

    def all_on_top(self) -> FloatArray:
        """All mass on the top: the popped cell, else the top value's data cells as ``q`` weighs them."""
        p_top = np.zeros_like(self.qv)
        if self.pop is not None:
            p_top[self.pop] = 1.0
        else:
            at_top = (self.qv > 0) & (self.v == self.top)
            p_top[at_top] = self.qv[at_top] / float(self.qv[at_top].sum())
        return p_top

    def top_divergence(self) -> float:
        """``I_φ`` of all mass on the top: every data cell loses its mass (φ(0) each), the top gains it."""
        div = self.div
        if self.pop is not None:
            return div.phi_at_zero + div.slope_at_infinity
        q_top = float(self.group_q[-1])
        return q_top * float(div.phi(np.array([1.0 / q_top]))[0]) + (1.0 - q_top) * div.phi_at_zero


def _ball(values: ArrayLike, q: ArrayLike, rho: float, divergence: str | Divergence) -> _Ball:
    """Check the inputs, merge equal data values and find the top the ball can reach."""
    div = get_divergence(divergence)
    v, qv = check_problem(values, q)
    r = check_rho(rho)
    full = qv > 0
    uniq, inverse, group_q = _merged(v[full], qv[full])
    pop = _popped(v, full, uniq, div)
    top = float(v[pop]) if pop is not None else float(uniq[-1])
    scale = top - float(uniq[0])
    mean = float(uniq[0]) if scale == 0.0 else float(np.dot(qv, v))
    return _Ball(div, v, qv, r, full, uniq, inverse, group_q, pop, top, scale, mean)


def _mapped_back(ball: _Ball, sol: ReducedSolution) -> WorstCase:
    """The reduced solution spread over the given cells (``q``-proportionally within a merged value)."""
    qv, full, inverse, group_q = ball.qv, ball.full, ball.inverse, ball.group_q
    p = np.zeros_like(qv)
    p[full] = sol.p[inverse] * qv[full] / group_q[inverse]
    if ball.pop is not None:
        p[ball.pop] = sol.p_pop
    p = np.maximum(p, 0.0)
    p /= p.sum()
    note = sol.note if ball.pop is None or sol.p_pop == 0.0 else f"{sol.note}; {sol.p_pop:.6g} popped"
    value = float(np.dot(p, ball.v))
    return ball.worst_case(p, "optimal", value, ball.mean + ball.scale * sol.eta, ball.scale * sol.lam, note)


def solve_exact(values: ArrayLike, q: ArrayLike, rho: float, divergence: str | Divergence) -> WorstCase:
    """``sup { Σ p_j f_j : p in the simplex, I_φ(p, q) <= ρ }`` exactly (Eq. (18), ball of Eq. (21)).

    Parameters
    ----------
    values
        Cell values ``f_j`` (any order; cells with ``q_j = 0`` are cells the data left empty).
    q
        Empirical probabilities.
    rho
        Radius, ``>= 0``.
    divergence
        Name (``"kl"``, ``"burg"``, ``"j"``, ``"chi2"``, ``"modified_chi2"``, ``"hellinger"``,
        ``"variation"``) or :class:`~services.fleet.dro.divergences.Divergence`.

    Returns
    -------
    WorstCase
        With ``status`` ``"optimal"``, ``"saturated"`` (the ball reaches all mass on the highest value it
        can reach: ``ρ >= I_φ(δ_top, q)`` to a relative ``1e-12``, e.g. ``-log q_top`` for KL,
        ``2 - 2 sqrt(q_top)`` Hellinger, ``2 (1 - q_top)`` variation, ``1/q_top - 1`` modified χ², 2 for
        Hellinger and variation when the top is an empty cell) or ``"degenerate"`` (one reachable value).

    Notes
    -----
    Cells of equal value are merged (the optimal ``p`` is proportional to ``q`` among them). A divergence
    without popping (``L = inf``) never puts mass on an empty cell; one with popping can, and only the
    highest empty cell above every data value can be worth it (a unit of mass costs ``L`` on any empty cell).
    Values are normalized to mean 0 and range 1 before any root finding.
    """
    ball = _ball(values, q, rho, divergence)
    mean, top, r = ball.mean, ball.top, ball.rho
    if ball.scale == 0.0:
        return ball.worst_case(
            ball.qv.copy(), "degenerate", mean, mean, 0.0, "one reachable value: the worst case for every rho"
        )
    i_top = ball.top_divergence()
    if i_top <= r * (1.0 + _SATURATION_RTOL):
        note = f"rho >= I(top, q) = {i_top:.6g}: all mass on the top"
        return ball.worst_case(ball.all_on_top(), "saturated", top, top, 0.0, note)
    if r == 0.0:
        return ball.worst_case(
            ball.qv.copy(), "optimal", mean, mean, math.inf, "rho = 0: the empirical distribution"
        )

    reduced = Reduced(
        f=(ball.uniq - mean) / ball.scale,
        q=ball.group_q,
        pop=(float(ball.v[ball.pop]) - mean) / ball.scale if ball.pop is not None else None,
        rho=r,
    )
    try:
        sol = SOLVERS[ball.div.name](reduced)
    except Unbracketed as edge:
        if edge.side == "above":
            note = "rho within rounding of saturation: all mass on the top"
            return ball.worst_case(ball.all_on_top(), "saturated", top, top, 0.0, note)
        note = "rho within rounding of 0: the empirical distribution"
        return ball.worst_case(ball.qv.copy(), "optimal", mean, mean, math.inf, note)
    return _mapped_back(ball, sol)


def dual_objective(
    values: ArrayLike, q: ArrayLike, rho: float, divergence: str | Divergence, eta: float, lam: float
) -> float:
    """The dual ``η + λρ + λ Σ_{q_j > 0} q_j φ*((f_j - η)/λ)``; ``inf`` if ``f_j - η > λ L`` on an empty cell.

    Every ``(η, λ >= 0)`` gives an upper bound on the worst case (weak duality); at the certificate of
    :func:`solve_exact` it equals the value. ``λ = 0`` means ``max f`` over the reachable cells if ``η`` is
    at least that, else ``inf``; ``λ = inf`` is the limit ``Σ q f``. A slack of ``1e-12`` is allowed on the
    conjugate's domain (``(f - η)/λ <= L``) for rounding.
    """
    div = get_divergence(divergence)
    v, qv = check_problem(values, q)
    r = check_rho(rho)
    full = qv > 0
    reach = full | (~full & div.popping)
    if math.isinf(lam) and lam > 0:
        return float(np.dot(qv, v))
    if lam < 0 or math.isnan(lam) or math.isnan(eta):
        raise DroInputError("lam", f"must be >= 0, got {lam}")
    if lam == 0.0:
        return float(eta) if bool(np.all(v[reach] <= eta)) else math.inf
    s = (v[full] - eta) / lam
    bound = div.slope_at_infinity
    if math.isfinite(bound):
        s = np.where((s > bound) & (s <= bound + _SLACK * (1.0 + abs(bound))), bound, s)
        if div.popping and np.any((v[~full] - eta) / lam > bound + _SLACK * (1.0 + abs(bound))):
            return math.inf
    return float(eta + lam * r + lam * float(np.dot(qv[full], div.conjugate(s))))
