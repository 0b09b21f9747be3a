"""Exact worst-case expectations, one solver per divergence, on a reduced and normalized problem.

The problem (docs/METHOD.md section 8, paper Eq. (18) with the ball of Eq. (21))::

    sup { Σ_j p_j f_j : p in the simplex, I_φ(p, q) <= ρ }

is handed over *reduced*: the distinct values ``f`` of the cells with ``q > 0`` (ascending, their ``q``
summed, ``Σ q = 1``), normalized to ``Σ q f = 0`` and range at most 1, plus, for a divergence that lets
mass pop, the value of the highest empty cell when it lies above every ``f`` (every other empty cell is
dominated: a unit of mass costs ``L`` on any of them). Saturation, ``ρ = 0`` and a single value are dealt
with by the caller (:mod:`services.fleet.dro.exact`).

Every solver returns the worst-case ``p`` over the reduced cells, the mass popped to the empty cell, and
the dual certificate ``(η, λ)`` of the convex dual (Ben-Tal et al. 2013)::

    inf_{λ >= 0, η}  η + λρ + λ Σ_{q_j > 0} q_j φ*((f_j - η) / λ),   with f_j - η <= λ L on empty cells,

whose value at ``(η, λ)`` equals the returned expectation. ``p`` is recovered from the dual by
``p_j = q_j (φ*)'((f_j - η) / λ)`` on the data's cells (the KKT conditions).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

from services.fleet.dro.divergences import j_inverse_derivative

__all__ = ["Reduced", "ReducedSolution", "SOLVERS", "Unbracketed"]

FloatArray = NDArray[np.float64]

_XTOL = 1e-14  # on log-parameters: relative accuracy of the multiplier
_RTOL = 4.0 * float(np.finfo(np.float64).eps)
_REACH = 700.0  # how far (in log units) a bracket may be searched


@dataclass(frozen=True, slots=True)
class Reduced:
    """The reduced problem: distinct values ``f`` (ascending, normalized), their ``q``, the pop cell, ρ."""

    f: FloatArray
    q: FloatArray
    pop: float | None
    rho: float

    @property
    def top(self) -> float:
        """The largest value mass may reach."""
        return self.pop if self.pop is not None else float(self.f[-1])


@dataclass(frozen=True, slots=True)
class ReducedSolution:
    """Worst-case masses of the reduced cells and of the pop cell, and the dual ``(η, λ)``."""

    p: FloatArray
    p_pop: float
    eta: float
    lam: float
    note: str


class Unbracketed(ArithmeticError):
    """No bracket for a multiplier in floating point: ρ is within rounding of 0 or of saturation."""

    def __init__(self, side: str) -> None:
        super().__init__(f"no bracket {side}")
        self.side = side


def _increasing_root(h: Callable[[float], float], x0: float, lo: float | None = None) -> float:
    """``x`` with ``h(x) = 0`` for an increasing ``h``; ``lo`` is a known point with ``h(lo) <= 0``."""
    a = x0 if lo is None else lo
    ha = h(a)
    if ha == 0.0:
        return a
    if ha < 0.0:
        b, step = a + 1.0, 1.0
        while h(b) < 0.0:
            a, step = b, 2.0 * step
            b = a + step
            if b - x0 > _REACH:
                raise Unbracketed("above")
    else:
        b, step = a, 1.0
        a = b - step
        while h(a) > 0.0:
            b, step = a, 2.0 * step
            a = b - step
            if x0 - a > _REACH:
                raise Unbracketed("below")
    return float(brentq(h, a, b, xtol=_XTOL, rtol=_RTOL, maxiter=500))


def _newton_increasing(
    fun: Callable[[float], tuple[float, float]], x: float, lo: float = -math.inf, hi: float = math.inf
) -> float:
    """Root of an increasing ``fun`` (returning value and derivative): Newton steps kept in a bracket.

    A step that leaves the known bracket ``(lo, hi)`` is replaced by bisection when both ends are known,
    and no step moves more than 4 units (the functions here are in log-parameters). Leaving ``±700`` (the
    exponent range of a double) raises :class:`Unbracketed`.
    """
    for _ in range(400):
        if not -_REACH <= x <= _REACH:
            raise Unbracketed("above" if x > 0 else "below")
        value, slope = fun(x)
        if value == 0.0:
            return x
        if value < 0.0:
            lo = max(lo, x)
        else:
            hi = min(hi, x)
        step = -value / slope if slope > 0.0 else math.copysign(4.0, -value)
        step = max(-4.0, min(4.0, step))
        nxt = x + step
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else x + step
        if abs(nxt - x) <= 1e-15 * (1.0 + abs(x)):
            return nxt
        x = nxt
    raise ArithmeticError(f"Newton's method did not converge (last x = {x})")


# ----------------------------------------------------------------------------------------- closed forms


def solve_variation(r: Reduced) -> ReducedSolution:
    """Variation distance: move ``ρ/2`` of the mass from the lowest values to the top (closed form).

    The dual multipliers are ``λ = (top - τ)/2`` and ``η = (top + τ)/2`` with ``τ`` the value of the cell
    where the removal stops.
    """
    f, q = r.f, r.q
    delta = 0.5 * r.rho
    cum = np.cumsum(q)
    k = int(np.searchsorted(cum, delta, side="right"))  # first cell not emptied
    k = min(k, f.size - 1)
    p = q.copy()
    p[:k] = 0.0
    p[k] = cum[k] - delta
    p_pop = 0.0
    if r.pop is not None:
        p_pop = delta
    else:
        p[-1] += delta
    tau, top = float(f[k]), r.top
    return ReducedSolution(p, p_pop, 0.5 * (top + tau), 0.5 * (top - tau), "closed form")


def solve_modified_chi2(r: Reduced) -> ReducedSolution:
    """Modified χ²: ``p_j ∝ q_j (f_j - τ)_+``, with ``τ`` in closed form on its active set.

    With every cell active this is ``mean + sqrt(ρ · var)``. When that ``p`` would go negative the lowest
    cells drop out: on the active set ``A`` (mass ``Q_A``, mean ``μ_A``, variance ``σ²_A``) the constraint
    gives ``μ_A - τ = σ_A / sqrt((1 + ρ) Q_A - 1)``, and the value is ``μ_A + σ_A sqrt((1 + ρ) Q_A - 1)``.
    Exactly one active set (a suffix of the sorted cells) puts ``τ`` between its lowest value and the
    highest dropped one.
    """
    f, q, rho = r.f, r.q, r.rho
    n = f.size
    s0 = np.cumsum(q[::-1])[::-1]
    s1 = np.cumsum((q * f)[::-1])[::-1]
    s2 = np.cumsum((q * f * f)[::-1])[::-1]
    dropped = np.concatenate([[0.0], np.cumsum(q)[:-1]])  # 1 - Q_A, without cancellation

    def excess_mass(k: int) -> float:  # (1 + ρ) Q_A - 1
        return rho * float(s0[k]) - float(dropped[k])

    best_k, best_violation, best_tau = 0, math.inf, math.nan
    for k in range(n):
        denom = excess_mass(k)
        if denom <= 0.0:
            break  # smaller active sets only lower Q_A
        mu = s1[k] / s0[k]
        var = float(np.dot(q, (f - mu) ** 2)) if k == 0 else max(float(s2[k] / s0[k] - mu * mu), 0.0)
        tau = float(mu - math.sqrt(var / denom))
        violation = max(0.0, tau - float(f[k]), (float(f[k - 1]) - tau) if k > 0 else 0.0)
        if violation < best_violation:
            best_k, best_violation, best_tau = k, violation, tau
        if violation == 0.0:
            break
    if best_k > 0:  # recompute on the chosen active set without the suffix-sum cancellation
        fa, qa = f[best_k:], q[best_k:]
        q0 = float(qa.sum())
        mu = float(np.dot(qa, fa)) / q0
        var = float(np.dot(qa, (fa - mu) ** 2)) / q0
        best_tau = mu - math.sqrt(var / excess_mass(best_k))
    excess = np.maximum(f - best_tau, 0.0)
    d = float(np.dot(q, excess))
    p = q * excess / d
    note = "closed form, mean + sqrt(rho var)" if best_k == 0 else f"closed form, {best_k} lowest cells at 0"
    return ReducedSolution(p, 0.0, best_tau + d, 0.5 * d, note)


# -------------------------------------------------------------------------------------- one-dimensional


def solve_kl(r: Reduced) -> ReducedSolution:
    """Kullback-Leibler: ``inf_{λ > 0} λρ + λ log Σ_j q_j exp(f_j / λ)`` by a root in ``θ = 1/λ``.

    The optimal ``p_j ∝ q_j exp(θ f_j)`` (exponential tilting); ``θ`` solves ``KL(p_θ, q) = ρ``, which is
    increasing in ``θ`` from 0 to ``-log q_top`` (saturation is handled before), with derivative
    ``θ Var_p(f)``: a bracketed Newton in ``log θ`` from the small-ρ answer ``θ = sqrt(2ρ / var)``.
    """
    f, q, rho = r.f, r.q, r.rho
    gap = f - f[-1]  # <= 0, so exp never overflows

    def tilt(x: float) -> tuple[float, float, FloatArray, float]:
        """KL(p_θ, q) - ρ, its derivative in ``x = log θ`` (θ² Var_p(f)), p_θ, and log Σ q e^{θ gap}."""
        theta = math.exp(x)
        z = theta * gap
        log_s = math.log1p(float(np.dot(q, np.expm1(z))))  # log Σ q e^z, accurate when z is small
        w = q * np.exp(z - log_s)
        mean_z = float(np.dot(w, z))
        return mean_z - log_s - rho, float(np.dot(w, (z - mean_z) ** 2)), w, log_s

    var = float(np.dot(q, f * f))  # f is centered: small ρ gives θ ≈ sqrt(2ρ / var)
    x = _newton_increasing(lambda x: tilt(x)[0:2], 0.5 * math.log(2.0 * rho / var))
    _, _, w, log_s = tilt(x)
    lam = math.exp(-x)
    return ReducedSolution(
        w, 0.0, lam * log_s + float(f[-1]), lam, "1-D dual root, Newton (exponential tilt)"
    )


def _jensen_gap(kind: str, f: FloatArray, q: FloatArray, d: float) -> float:
    """``g(β)``, the divergence of the non-popping KKT point at ``β = f_top + d`` (decreasing in ``d``).

    Burg: ``log E[b] - E[log b]``; χ²: ``E[c] E[1/c] - 1``; Hellinger: ``2 - 2 E[b] / sqrt(E[b²])``, with
    ``b = β / (β - f)`` and ``c = sqrt(b)``; each written without cancellation between O(1) terms.
    """
    y = f / (float(f[-1]) - f + d)  # b - 1
    if kind == "burg":
        u = float(np.dot(q, y))
        return math.log1p(u) - float(np.dot(q, np.log1p(y)))
    if kind == "chi2":
        e = y / (np.sqrt(1.0 + y) + 1.0)  # c - 1
        ebar = float(np.dot(q, e))
        return float(np.dot(q, (e - ebar) ** 2 / ((1.0 + e) * (1.0 + ebar))))
    u = float(np.dot(q, y))
    var = float(np.dot(q, (y - u) ** 2))
    ratio = var / float(np.dot(q, (1.0 + y) ** 2))
    return 2.0 * ratio / (1.0 + math.sqrt(max(1.0 - ratio, 0.0)))


def _beta_family(kind: str, r: Reduced) -> ReducedSolution:
    """Burg, χ² and Hellinger: one root in ``β = η + λ``, then ``p`` from ``β``; popping in closed form.

    KKT on the data's cells: Burg ``p_j = q_j λ / (β - f_j)``, χ² ``p_j = q_j sqrt(λ / (β - f_j))``,
    Hellinger ``p_j = q_j λ² / (β - f_j)²``; ``Σ p = 1`` fixes ``λ`` given ``β`` and ``I_φ(p, q) = ρ`` fixes
    ``β > f_top``. Mass pops to the empty cell ``E`` when even ``β = f_E`` leaves budget (``g(f_E) < ρ``);
    then ``β = f_E`` and ``λ`` spends the budget, the popped mass being ``1 - Σ p``: Burg
    ``log λ = Σ q log(f_E - f) - ρ`` (``I = Σ q log(q/p)``: popped mass is free beyond what it takes from
    the data); χ² ``sqrt(λ) Σ q / sqrt(f_E - f) = (1 + g(f_E)) / (1 + ρ)``; Hellinger
    ``λ = (2 - ρ) / (2 Σ q / (f_E - f))``.
    """
    f, q, rho = r.f, r.q, r.rho
    top = float(f[-1])
    gap = top - f

    if r.pop is not None:
        d_pop = r.pop - top
        g_pop = _jensen_gap(kind, f, q, d_pop)
        if g_pop < rho:
            a = 1.0 / (gap + d_pop)
            if kind == "burg":
                lam = math.exp(-float(np.dot(q, np.log(a))) - rho)
                p = q * lam * a
            elif kind == "chi2":
                t = (1.0 + g_pop) / (1.0 + rho)
                root_a = np.sqrt(a)
                sqrt_lam = t / float(np.dot(q, root_a))
                lam = sqrt_lam * sqrt_lam
                p = q * sqrt_lam * root_a
            else:
                lam = (2.0 - rho) / (2.0 * float(np.dot(q, a)))
                p = q * (lam * a) ** 2
            p_pop = max(1.0 - float(p.sum()), 0.0)
            return ReducedSolution(p, p_pop, r.pop - lam, lam, "popping, closed form at beta = f_E")
        lo = math.log(d_pop)  # g(d_pop) >= ρ: the root lies at or above d_pop
    else:
        lo = None

    x = _increasing_root(lambda x: rho - _jensen_gap(kind, f, q, math.exp(x)), 0.0, lo)
    d = math.exp(x)
    a = 1.0 / (gap + d)
    if kind == "burg":
        lam = 1.0 / float(np.dot(q, a))
        p = q * lam * a
    elif kind == "chi2":
        root_a = np.sqrt(a)
        sqrt_lam = 1.0 / float(np.dot(q, root_a))
        lam = sqrt_lam * sqrt_lam
        p = q * sqrt_lam * root_a
    else:
        lam = 1.0 / math.sqrt(float(np.dot(q, a * a)))
        p = q * (lam * a) ** 2
    return ReducedSolution(p, 0.0, top + d - lam, lam, "1-D dual root in beta = eta + lambda")


def solve_burg(r: Reduced) -> ReducedSolution:
    """Burg entropy (``φ* (s) = -log(1 - s)``); see :func:`_beta_family`."""
    return _beta_family("burg", r)


def solve_chi2(r: Reduced) -> ReducedSolution:
    """χ² (``φ*(s) = 2 - 2 sqrt(1 - s)``); see :func:`_beta_family`."""
    return _beta_family("chi2", r)


def solve_hellinger(r: Reduced) -> ReducedSolution:
    """Hellinger (``φ*(s) = s / (1 - s)``); see :func:`_beta_family`."""
    return _beta_family("hellinger", r)


# ------------------------------------------------------------------------------------------ J-divergence


def _j_newton(f: FloatArray, q: FloatArray, rho: float, c_hi: float) -> tuple[float, float] | None:
    """Newton's method on both KKT equations of :func:`solve_j` at once; ``None`` unless it converges.

    Unknowns ``(log a, c)``; equations ``Σ q t - 1 = 0`` and ``Σ q φ(t) - ρ = 0``; backtracking on the
    squared residual. Fast from the small-ρ start (a few iterations), but without a global guarantee: the
    nested roots are the fallback.
    """
    gap = f[-1] - f
    log_a = 0.5 * math.log(4.0 * rho / float(np.dot(q, f * f)))  # small ρ: t ≈ 1 + a (f - mean) / 2
    c = min(max(0.5 * math.exp(log_a) * float(f[-1]), 0.0), c_hi)

    def residual(log_a: float, c: float) -> tuple[float, float, FloatArray, FloatArray]:
        s = c - math.exp(log_a) * gap
        x = j_inverse_derivative(s)
        return float(np.dot(q, np.exp(x))) - 1.0, float(np.dot(q, np.expm1(x) * x)) - rho, x, s

    r1, r2, x, s = residual(log_a, c)
    merit = r1 * r1 + (r2 / rho) ** 2
    for _ in range(60):
        if abs(r1) <= 1e-14 and abs(r2) <= 1e-12 * rho:
            return log_a, c
        t = np.exp(x)
        u = q * t * t / (t + 1.0)
        a = math.exp(log_a)
        j11, j12 = float(u.sum()), -a * float(np.dot(u, gap))
        j21, j22 = float(np.dot(u, s)), -a * float(np.dot(u * s, gap))
        det = j11 * j22 - j12 * j21
        if not (det != 0.0 and math.isfinite(det)):
            return None
        d_log_a = (-j11 * r2 + j21 * r1) / det
        d_c = (-j22 * r1 + j12 * r2) / det
        step = min(1.0, 4.0 / abs(d_log_a)) if d_log_a != 0.0 else 1.0
        while True:
            c_new = min(max(c + step * d_c, 0.0), c_hi)
            n1, n2, x_new, s_new = residual(log_a + step * d_log_a, c_new)
            m_new = n1 * n1 + (n2 / rho) ** 2
            if m_new < merit or m_new == 0.0:
                break
            step *= 0.5
            if step < 1e-6:
                return None
        log_a, c, r1, r2, x, s, merit = log_a + step * d_log_a, c_new, n1, n2, x_new, s_new, m_new
    return None


def solve_j(r: Reduced, *, fast: bool = True) -> ReducedSolution:
    """J-divergence (``φ(t) = (t - 1) log t``, no closed-form φ*): the 2-D dual, by Newton or nested roots.

    The KKT point is ``p_j = q_j t_j`` with ``φ'(t_j) = (f_j - η)/λ`` (``φ'(t) = log t + 1 - 1/t``, inverted
    by :func:`~services.fleet.dro.divergences.j_inverse_derivative`). Written from the top cell,
    ``φ'(t_j) = c - a g_j`` with ``a = 1/λ``, ``c = φ'(t_top)`` and ``g_j = f_top - f_j >= 0`` (no
    cancellation however small λ gets). ``fast``: Newton's method on both equations first. Otherwise, or
    when it does not converge, nested roots: for each ``a`` the ``c`` with ``Σ q t = 1`` lies in
    ``[0, φ'(1/q_top)]`` and ``Σ q t`` is convex increasing in ``c`` (bracketed Newton); then ``a`` solves
    ``I_J(p, q) = ρ``, which increases from 0 to infinity in ``a`` (no suppression, no saturation) with
    ``dI/da = a Σ w (g - ḡ)²`` (``w = q / φ''(t)``, ``ḡ`` its weighted mean): a bracketed Newton in ``log a``.
    """
    f, q, rho = r.f, r.q, r.rho
    gap = f[-1] - f
    t_top = 1.0 / float(q[-1])
    c_hi = math.log(t_top) + 1.0 - 1.0 / t_top
    state = {"c": 0.0}

    def normalize(a: float) -> tuple[FloatArray, FloatArray, float]:
        c = min(max(state["c"], 0.0), c_hi)
        lo, hi = 0.0, c_hi
        x = np.zeros_like(f)
        for _ in range(200):
            x = j_inverse_derivative(c - a * gap)
            t = np.exp(x)
            excess = float(np.dot(q, t)) - 1.0
            if excess == 0.0:
                break
            if excess < 0.0:
                lo = c
            else:
                hi = c
            nxt = c - excess / float(np.dot(q, t * t / (t + 1.0)))
            if not lo < nxt < hi:
                nxt = 0.5 * (lo + hi)
            if abs(nxt - c) <= 1e-15 * (1.0 + abs(c)):
                x = j_inverse_derivative(nxt - a * gap)
                c = nxt
                break
            c = nxt
        t = np.exp(x)
        state["c"] = c
        return x, q * t * t / (t + 1.0), c

    def divergence_gap(log_a: float) -> tuple[float, float]:
        a = math.exp(log_a)
        x, w, _ = normalize(a)
        gbar = float(np.dot(w, gap)) / float(w.sum())
        return float(np.dot(q, np.expm1(x) * x)) - rho, a * a * float(np.dot(w, (gap - gbar) ** 2))

    found = _j_newton(f, q, rho, c_hi) if fast else None
    if found is not None:
        log_a, c = found
        x = j_inverse_derivative(c - math.exp(log_a) * gap)
        note = "2-D dual, Newton on the KKT equations"
    else:
        log_a = _newton_increasing(divergence_gap, 0.5 * math.log(4.0 * rho / float(np.dot(q, f * f))))
        x, _, c = normalize(math.exp(log_a))
        note = "2-D dual as nested bracketed Newton roots"
    t = np.exp(x)
    p = q * t / float(np.dot(q, t))
    lam = math.exp(-log_a)
    return ReducedSolution(p, 0.0, float(f[-1]) - lam * c, lam, note)


SOLVERS: Mapping[str, Callable[[Reduced], ReducedSolution]] = MappingProxyType(
    {
        "kl": solve_kl,
        "burg": solve_burg,
        "j": solve_j,
        "chi2": solve_chi2,
        "modified_chi2": solve_modified_chi2,
        "hellinger": solve_hellinger,
        "variation": solve_variation,
    }
)
"""The exact solver of each divergence (on the reduced problem)."""
