"""Request and response models of the stateless DRO endpoint, and the conversion from the core's result."""

from __future__ import annotations

from typing import Annotated, Literal, cast

from pydantic import BeforeValidator, Field, Strict, ValidationInfo, field_validator

from app.schemas.common import RequestModel, ResponseModel, integral
from app.settings import DivergenceName
from services.fleet.dro import WorstCase

__all__ = ["MAX_SAMPLES", "MAX_BINS", "WorstCaseIn", "WorstCaseOut"]

MAX_SAMPLES = 100_000
MAX_BINS = 1_000

FiniteFloat = Annotated[float, Strict(), Field(allow_inf_nan=False)]


class WorstCaseIn(RequestModel):
    """KPI samples and the ambiguity set around their empirical distribution (docs/METHOD.md section 8)."""

    samples: list[FiniteFloat] = Field(
        min_length=2, max_length=MAX_SAMPLES, description="KPI samples f^1..f^M (finite numbers)."
    )
    divergence: DivergenceName = Field(default="kl", description="The φ-divergence of the ball.")
    alpha: Annotated[float, Strict()] | None = Field(
        default=None,
        gt=0.0,
        lt=1.0,
        description="Significance level of the radius rule ρ = φ''(1)/(2M) χ²_{m-1,1-α}; 0.05 when neither "
        "alpha nor rho is given.",
    )
    rho: FiniteFloat | None = Field(default=None, ge=0.0, description="The radius itself (instead of alpha).")
    support: Literal["binned", "samples"] = Field(
        default="binned", description="Equal-width bins over [min, max] (m = bins), or one cell per sample."
    )
    bins: Annotated[int, Strict(), Field(ge=2, le=MAX_BINS), BeforeValidator(integral)] = Field(
        default=10, description="Number of bins (binned support); 4.0 is 4."
    )
    method: Literal["exact", "box_lp"] = Field(
        default="exact", description="The exact worst case, or the paper's box LP (Eq. 28, binned only)."
    )

    @field_validator("rho")
    @classmethod
    def _not_both(cls, rho: float | None, info: ValidationInfo) -> float | None:
        if rho is not None and info.data.get("alpha") is not None:
            raise ValueError("give alpha or rho, not both")
        return rho

    @field_validator("method")
    @classmethod
    def _box_lp_needs_bins(cls, method: str, info: ValidationInfo) -> str:
        if method == "box_lp" and info.data.get("support") == "samples":
            raise ValueError("box_lp works on bins: use support 'binned'")
        return method


class WorstCaseOut(ResponseModel):
    """The worst-case expected KPI, the empirical mean, and the distributions on the support's cells."""

    value: float = Field(description="The worst-case expectation sup Σ p_j f_j over the ball.")
    mean: float = Field(description="Σ q_j f_j: the expectation at ρ = 0 (the sample mean for bin means).")
    rho: float = Field(description="The radius used.")
    m: int = Field(description="Number of cells.")
    support_values: list[float] = Field(description="Cell values, ascending (bin means or midpoints).")
    q: list[float] = Field(description="Empirical probabilities of the cells.")
    p: list[float] = Field(description="The worst-case distribution over the cells.")
    status: Literal["optimal", "saturated", "degenerate"] = Field(
        description="optimal; saturated (all mass on the highest reachable value); degenerate (one value)."
    )
    divergence: DivergenceName
    method: Literal["exact", "box_lp"]

    @classmethod
    def of(cls, wc: WorstCase) -> WorstCaseOut:
        """From the core's result."""
        return cls(
            value=wc.value,
            mean=wc.mean,
            rho=wc.rho,
            m=wc.m,
            support_values=wc.support_values.tolist(),
            q=wc.q.tolist(),
            p=wc.p.tolist(),
            status=wc.status,
            divergence=cast(DivergenceName, wc.divergence),
            method=wc.method,
        )
