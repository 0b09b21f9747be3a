"""Models of the operational routes (``app.api.ops``): liveness and readiness."""

from __future__ import annotations

from typing import Literal

from app.schemas.common import ResponseModel

__all__ = ["HealthOut", "ReadyOut"]


class HealthOut(ResponseModel):
    """Liveness."""

    status: Literal["ok"]


class ReadyOut(ResponseModel):
    """Readiness: store reachable and cities loaded."""

    status: Literal["ready"]
    store: str
    cities: list[str]
