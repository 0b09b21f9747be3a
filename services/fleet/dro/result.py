"""The result of a worst-case expectation, with its status and diagnostics."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

__all__ = ["Status", "Method", "METHODS", "WorstCase"]

Status = Literal["optimal", "saturated", "degenerate"]
"""``optimal``: solved, the ball binds; ``saturated``: the ball reaches the distribution that puts all mass on
the highest reachable value, so the answer is that value; ``degenerate``: one distinct value, which is the
answer for every ρ."""

Method = Literal["exact", "box_lp"]
METHODS: tuple[Method, ...] = ("exact", "box_lp")


@dataclass(frozen=True, slots=True)
class WorstCase:
    """``sup { Σ p_j f_j : p in the simplex, I_φ(p, q) <= ρ }`` and the distribution attaining it.

    Attributes
    ----------
    value
        The worst-case expectation.
    mean
        ``Σ q_j f_j``, the expectation under the empirical distribution on this support (the value at
        ``ρ = 0``; the sample mean for bin means or one cell per sample).
    rho, m
        The radius and the number of cells.
    support_values, q, p
        Cell values (ascending), empirical and worst-case probabilities.
    status
        See :data:`Status`.
    divergence, method
        The divergence's name; ``"exact"`` or ``"box_lp"``.
    eta, lam
        The dual certificate ``(η, λ)`` (exact method): the dual objective there equals ``value``. ``λ = 0``
        when saturated or degenerate, ``λ = inf`` when ``ρ = 0``; ``nan`` for the box LP.
    divergence_at_p
        ``I_φ(p, q)``: at most ρ (to rounding) for the exact method; the box LP's ``p`` may exceed it.
    note
        How the answer was obtained (closed form, root, popping, why saturated, ...).
    """

    value: float
    mean: float
    rho: float
    m: int
    support_values: NDArray[np.float64]
    q: NDArray[np.float64]
    p: NDArray[np.float64]
    status: Status
    divergence: str
    method: Method
    eta: float
    lam: float
    divergence_at_p: float
    note: str

    @property
    def premium(self) -> float:
        """``value - mean``: what robustness adds to the nominal expectation."""
        return self.value - self.mean
