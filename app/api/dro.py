"""Stateless DRO route: the worst-case expected KPI over a φ-divergence ball (scope `read`)."""

from __future__ import annotations

from fastapi import APIRouter

from app.api.bodies import WorstCaseBody, request_body
from app.api.deps import ReadAccess
from app.api.responses import errors
from app.errors import InvalidInput
from app.schemas.dro import WorstCaseIn, WorstCaseOut
from services.fleet.dro import DroInputError, worst_case

__all__ = ["router"]

router = APIRouter(prefix="/v1/dro", tags=["dro"], responses=errors(400, 401, 403, 413, 415, 422, 500))


@router.post(
    "/worst-case",
    response_model=WorstCaseOut,
    summary="Worst-case expected KPI",
    openapi_extra=request_body(WorstCaseIn),
)
def post_worst_case(_: ReadAccess, body: WorstCaseBody) -> WorstCaseOut:
    """Solve sup Σ p_j f_j over {p : I_φ(p, q) <= ρ} around the samples' empirical distribution (no state)."""
    try:
        result = worst_case(
            body.samples,
            body.divergence,
            alpha=body.alpha,
            rho=body.rho,
            support=body.support,
            bins=body.bins,
            method=body.method,
        )
    except DroInputError as exc:  # what only the core can see, e.g. a range too wide to represent
        raise InvalidInput.at(exc.parameter, exc.message) from None
    return WorstCaseOut.of(result)
