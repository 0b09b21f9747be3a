"""The paper's box-constrained LP (Eq. (28)): an outer approximation of the worst-case expectation.

Each ``p_i`` is bounded by the projection of the φ-ball on coordinate ``i`` (Eq. (27)),
``[p̲_i, p̄_i] = {p_i : p in the simplex, I_φ(p, q) <= ρ}``, and the LP maximizes ``Σ g_i p_i`` over the
simplex intersected with that box. The box contains the ball, so the LP's value is at least the exact worst
case on the same cells; on realistic data it overstates it considerably (docs/METHOD.md section 8: about
10-28 %).

Equation numbers count the paper's numbered equations as the rest of the code does (sensing Eq. (1)-(3),
matching (4)-(16)); docs/METHOD.md section 8 calls this LP "Eq. (24)".
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog

from services.fleet.dro.divergences import Divergence, divergence_value, get_divergence
from services.fleet.dro.exact import check_problem
from services.fleet.dro.inputs import check_rho
from services.fleet.dro.result import Status, WorstCase

__all__ = ["coordinate_bounds", "solve_box_lp"]

FloatArray = NDArray[np.float64]
_BISECTIONS = 80  # halves [0, 1] below 1e-24: every bound to the last bit


def _cheapest(div: Divergence, q: FloatArray, x: FloatArray) -> FloatArray:
    """``D_i(x)``: the least ``I_φ(p, q)`` over the simplex with ``p_i = x``, for every cell ``i`` at once.

    The rest of the mass is spread in proportion to ``q`` over the other data cells (Jensen), never on an
    empty cell (there a unit costs ``L`` > φ' anywhere). A data cell ``i``:
    ``q_i φ(x / q_i) + (1 - q_i) φ((1 - x) / (1 - q_i))``; an empty cell: ``x L + φ(1 - x)``.
    """
    rest = 1.0 - q
    with np.errstate(divide="ignore", invalid="ignore"):
        own = np.where(q > 0, q * div.phi_1p((x - q) / np.where(q > 0, q, 1.0)), 0.0)
        own = np.where((q == 0) & (x > 0), x * div.slope_at_infinity, own)
        others = np.where(rest > 0, rest * div.phi_1p((q - x) / np.where(rest > 0, rest, 1.0)), 0.0)
        # a lone data cell: what leaves it can only go to empty cells
        others = np.where((rest <= 0) & (x < 1), (1.0 - x) * div.slope_at_infinity, others)
    return np.asarray(own + others, dtype=np.float64)


def coordinate_bounds(
    q: ArrayLike, rho: float, divergence: str | Divergence
) -> tuple[FloatArray, FloatArray]:
    """``(p̲, p̄)``: the projections of the ball ``{p in the simplex : I_φ(p, q) <= ρ}`` on each coordinate.

    ``D_i`` is convex with ``D_i(q_i) = 0``, so each bound is where ``D_i`` crosses ρ on either side of
    ``q_i``, found by bisection for all cells at once (the returned bound lies inside the ball).
    """
    div = get_divergence(divergence)
    qv = np.asarray(q, dtype=np.float64)
    r = check_rho(rho)

    def bound(outer: FloatArray) -> FloatArray:
        inside = qv.copy()  # D(inside) <= ρ
        out = outer.copy()
        done = _cheapest(div, qv, out) <= r
        inside[done] = out[done]
        for _ in range(_BISECTIONS):
            mid = 0.5 * (inside + out)
            ok = _cheapest(div, qv, mid) <= r
            inside = np.where(ok & ~done, mid, inside)
            out = np.where(~ok & ~done, mid, out)
        return inside

    return bound(np.zeros_like(qv)), bound(np.ones_like(qv))


def solve_box_lp(values: ArrayLike, q: ArrayLike, rho: float, divergence: str | Divergence) -> WorstCase:
    """``max { Σ g_i p_i : Σ p_i = 1, p̲_i <= p_i <= p̄_i }`` (Eq. (28)) with ``scipy.optimize.linprog``.

    ``values`` are the grid points (the paper's bin midpoints ``g_i = L + (i - 1/2) Δ``). The returned ``p``
    lies in the box, not necessarily in the ball: ``divergence_at_p`` may exceed ρ. ``eta`` and ``lam`` are
    ``nan``. Status ``"saturated"`` when all mass lands on the highest reachable value, ``"degenerate"``
    when only one value is reachable.
    """
    div = get_divergence(divergence)
    g, qv = check_problem(values, q)
    r = check_rho(rho)
    mean = float(np.dot(qv, g))
    lower, upper = coordinate_bounds(qv, r, div)
    reach = upper > 0
    top = float(g[reach].max())
    if float(g[reach].min()) == top:
        return WorstCase(
            top,
            top,
            r,
            int(g.size),
            g,
            qv,
            qv.copy(),
            "degenerate",
            div.name,
            "box_lp",
            math.nan,
            math.nan,
            0.0,
            "one reachable value",
        )
    res = linprog(
        -g,
        A_eq=np.ones((1, g.size)),
        b_eq=np.ones(1),
        bounds=np.column_stack([lower, upper]),
        method="highs",
    )
    if res.status != 0:  # the box always contains q, so this is a solver failure, never infeasibility
        raise ArithmeticError(f"box LP failed: {res.message}")
    p = np.clip(np.asarray(res.x, dtype=np.float64), lower, upper)
    p /= p.sum()
    status: Status = "saturated" if float(p[g == top].sum()) >= 1.0 - 1e-12 else "optimal"
    return WorstCase(
        value=float(np.dot(p, g)),
        mean=mean,
        rho=r,
        m=int(g.size),
        support_values=g,
        q=qv,
        p=p,
        status=status,
        divergence=div.name,
        method="box_lp",
        eta=math.nan,
        lam=math.nan,
        divergence_at_p=divergence_value(p, qv, div),
        note="paper Eq. (28): LP over the box of coordinate projections (outer approximation)",
    )
