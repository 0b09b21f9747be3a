"""Input checks shared by the DRO engine: one error type that names the offending parameter."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["DroInputError", "as_samples", "check_alpha", "check_rho"]


class DroInputError(ValueError):
    """A bad argument to the DRO engine; ``parameter`` names it (``"samples"``, ``"alpha"``, ...)."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(f"{parameter}: {message}")
        self.parameter = parameter
        self.message = message


def as_samples(samples: ArrayLike, *, minimum: int = 2) -> NDArray[np.float64]:
    """The samples as a 1-D float array: at least ``minimum`` finite values spanning a finite range."""
    try:
        x = np.asarray(samples, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DroInputError("samples", f"must be a list of numbers ({exc})") from None
    if x.ndim != 1:
        raise DroInputError("samples", f"must be one-dimensional, got shape {x.shape}")
    if x.size < minimum:
        raise DroInputError("samples", f"needs at least {minimum} values, got {x.size}")
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise DroInputError("samples", f"must be finite; value {x[bad[0]]} at index {int(bad[0])}")
    with np.errstate(over="ignore"):
        span = float(x.max() - x.min())
    if not math.isfinite(span):
        raise DroInputError("samples", "span too wide a range to represent (max - min overflows)")
    return x


def check_alpha(alpha: float) -> float:
    """A significance level in the open interval (0, 1)."""
    a = float(alpha)
    if not (0.0 < a < 1.0):
        raise DroInputError("alpha", f"must lie strictly between 0 and 1, got {alpha}")
    return a


def check_rho(rho: float) -> float:
    """A finite, non-negative radius."""
    r = float(rho)
    if not math.isfinite(r) or r < 0.0:
        raise DroInputError("rho", f"must be finite and >= 0, got {rho}")
    return r
