"""The test oracle: the primal convex program of the worst-case expectation, in cvxpy (CLARABEL).

An independent formulation of ``max Σ p f s.t. p in the simplex, I_φ(p, q) <= ρ``: each divergence is
written with cvxpy atoms from its definition in the paper's Table A.1; a data cell costs ``q φ(p/q)``, an
empty cell ``p L`` when mass may pop there, and is fixed at 0 otherwise.
"""

from __future__ import annotations

import warnings

import cvxpy as cp
import numpy as np
from numpy.typing import NDArray

__all__ = ["POPPING", "primal_max", "primal_worst_case", "textbook_divergence"]

POPPING = {
    "kl": False,
    "burg": True,
    "j": False,
    "chi2": True,
    "modified_chi2": False,
    "hellinger": True,
    "variation": True,
}


def _divergence(name: str, p: cp.Expression, q: NDArray[np.float64]) -> cp.Expression:
    if name == "kl":  # q φ(p/q) = p log(p/q) - p + q
        return cp.sum(cp.kl_div(p, q))
    if name == "burg":  # q φ(p/q) = q log(q/p) + p - q
        return cp.sum(cp.kl_div(q, p))
    if name == "j":  # (p - q) log(p/q)
        return cp.sum(cp.kl_div(p, q) + cp.kl_div(q, p))
    if name == "modified_chi2":  # (p - q)^2 / q
        return cp.sum_squares(cp.multiply(1 / np.sqrt(q), p - q))
    if name == "hellinger":  # (sqrt p - sqrt q)^2 = p + q - 2 sqrt(p q)
        return cp.sum(p + q - 2 * cp.multiply(np.sqrt(q), cp.sqrt(p)))
    if name == "variation":
        return cp.sum(cp.abs(p - q))
    raise ValueError(name)


def primal_max(
    c: NDArray[np.float64],
    q: NDArray[np.float64],
    rho: float,
    divergence: str,
    *,
    tol: float | None = 1e-11,
    timing: dict[str, float] | None = None,
) -> tuple[float, NDArray[np.float64]]:
    """``max c·p`` over ``{p in the simplex : I_φ(p, q) <= ρ}`` and the maximizer.

    ``tol``: CLARABEL's gap and feasibility tolerances (``None``: the solver's defaults). ``timing``, when
    given, receives cvxpy's ``compile_s`` and the solver's own ``solve_s``.
    """
    full = q > 0
    p = cp.Variable(q.size, nonneg=True)
    cons: list[cp.Constraint] = [cp.sum(p) == 1]
    pf = p[np.flatnonzero(full)]
    if divergence == "chi2":  # (p - q)^2 / p <= s  as the cone  ||(2(p - q), p - s)|| <= p + s
        s = cp.Variable(int(full.sum()), nonneg=True)
        cons.append(cp.SOC(pf + s, cp.vstack([2 * (pf - q[full]), pf - s]), axis=0))
        cost = cp.sum(s)
    else:
        cost = _divergence(divergence, pf, q[full])
    if not full.all():
        empty = np.flatnonzero(~full)
        if POPPING[divergence]:
            cost = cost + cp.sum(p[empty])
        else:
            cons.append(p[empty] == 0)
    cons.append(cost <= rho)
    prob = cp.Problem(cp.Maximize(c @ p), cons)
    with warnings.catch_warnings():  # "may be inaccurate" at these tight tolerances; callers check the value
        warnings.simplefilter("ignore", UserWarning)
        if tol is None:
            prob.solve(solver=cp.CLARABEL)
        else:
            prob.solve(solver=cp.CLARABEL, tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol, max_iter=500)
    if prob.status not in ("optimal", "optimal_inaccurate"):
        raise RuntimeError(f"cvxpy: {prob.status}")
    if timing is not None:
        timing["compile_s"] = float(prob.compilation_time or 0.0)
        timing["solve_s"] = float(prob.solver_stats.solve_time or 0.0)
    return float(prob.value), np.asarray(p.value, dtype=np.float64)


def primal_worst_case(
    values: NDArray[np.float64],
    q: NDArray[np.float64],
    rho: float,
    divergence: str,
    *,
    tol: float | None = 1e-11,
    timing: dict[str, float] | None = None,
) -> tuple[float, NDArray[np.float64]]:
    """Optimal value and ``p`` of the primal (values are normalized to [0, 1] for the solver's sake)."""
    lo, hi = float(values.min()), float(values.max())
    scale = hi - lo if hi > lo else 1.0
    value, p = primal_max((values - lo) / scale, q, rho, divergence, tol=tol, timing=timing)
    return lo + scale * value, p


def textbook_divergence(p: NDArray[np.float64], q: NDArray[np.float64], divergence: str) -> float:
    """``I_φ(p, q)`` straight from the paper's Table A.1 (third column), summed over every cell.

    On an empty cell (``q = 0``) the formulas' limits apply: ``p log(p/0)`` and ``p²/0`` are infinite for
    ``p > 0`` (KL, J, modified χ²: no popping), ``q log(q/p)`` is 0 (Burg), ``(p - q)²/p``,
    ``(sqrt p - sqrt q)²`` and ``|p - q|`` are ``p``.
    """
    full = q > 0
    pf, qf = p[full], q[full]
    with np.errstate(divide="ignore", invalid="ignore"):
        if divergence == "kl":
            terms = np.where(pf > 0, pf * np.log(pf / qf), 0.0)
        elif divergence == "burg":
            terms = qf * np.log(qf / pf)
        elif divergence == "j":
            terms = (pf - qf) * np.log(pf / qf)
        elif divergence == "chi2":
            terms = (pf - qf) ** 2 / pf
        elif divergence == "modified_chi2":
            terms = (pf - qf) ** 2 / qf
        elif divergence == "hellinger":
            terms = (np.sqrt(pf) - np.sqrt(qf)) ** 2
        elif divergence == "variation":
            terms = np.abs(pf - qf)
        else:
            raise ValueError(divergence)
    total = float(np.sum(terms))
    popped = float(np.sum(p[~full]))
    if popped > 0 and divergence in ("kl", "j", "modified_chi2"):
        return np.inf
    if divergence in ("chi2", "hellinger", "variation"):
        total += popped
    return total
