"""Annotated dependencies: the use cases, metrics, settings and bearer-token auth with scopes."""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Path, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from app.api.inputs import Limits
from app.errors import Forbidden, Unauthorized
from app.metrics import Metrics
from app.settings import Scope, Settings
from app.usecases import (
    AdminService,
    CityCatalog,
    CoverageService,
    EpochService,
    FleetService,
    ReadinessService,
    TaskService,
    UseCases,
)

__all__ = [
    "Principal",
    "CitiesDep",
    "EpochsDep",
    "TasksDep",
    "AdminDep",
    "CoverageDep",
    "ReadinessDep",
    "FleetDep",
    "MetricsDep",
    "SettingsDep",
    "LimitsDep",
    "ReadAccess",
    "DispatchAccess",
    "AdminAccess",
    "CityName",
]


def _use_cases(request: Request) -> UseCases:
    use_cases: UseCases = request.app.state.use_cases
    return use_cases


async def get_cities(request: Request) -> CityCatalog:
    """The served cities."""
    return _use_cases(request).cities


async def get_epochs(request: Request) -> EpochService:
    """The epoch use cases."""
    return _use_cases(request).epochs


async def get_tasks(request: Request) -> TaskService:
    """The task use cases."""
    return _use_cases(request).tasks


async def get_admin(request: Request) -> AdminService:
    """The admin use cases."""
    return _use_cases(request).admin


async def get_coverage(request: Request) -> CoverageService:
    """The coverage use case."""
    return _use_cases(request).coverage


async def get_readiness(request: Request) -> ReadinessService:
    """The readiness use case."""
    return _use_cases(request).readiness


async def get_fleet(request: Request) -> FleetService:
    """The fleet-sizing use cases."""
    return _use_cases(request).fleet


async def get_metrics(request: Request) -> Metrics:
    """The app's metrics."""
    metrics: Metrics = request.app.state.metrics
    return metrics


async def get_settings(request: Request) -> Settings:
    """The app's settings."""
    settings: Settings = request.app.state.settings
    return settings


CitiesDep = Annotated[CityCatalog, Depends(get_cities)]
EpochsDep = Annotated[EpochService, Depends(get_epochs)]
TasksDep = Annotated[TaskService, Depends(get_tasks)]
AdminDep = Annotated[AdminService, Depends(get_admin)]
CoverageDep = Annotated[CoverageService, Depends(get_coverage)]
ReadinessDep = Annotated[ReadinessService, Depends(get_readiness)]
FleetDep = Annotated[FleetService, Depends(get_fleet)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
SettingsDep = Annotated[Settings, Depends(get_settings)]


async def get_limits(settings: SettingsDep) -> Limits:
    """Items per request, from the settings."""
    return Limits.from_settings(settings)


LimitsDep = Annotated[Limits, Depends(get_limits)]

_bearer = HTTPBearer(
    auto_error=False,
    description="A token from SD_TOKENS; GET /v1/... needs scope `read`, epoch and task posts `dispatch`, "
    "POST /v1/dro/worst-case `read`, POST .../fleet/solve and .../admin/* `admin`.",
)


@dataclass(frozen=True, slots=True)
class Principal:
    """An authenticated caller (identified by a token prefix, never the whole token)."""

    name: str
    scopes: frozenset[Scope]


async def _principal(
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    if credentials is None or not credentials.credentials:
        raise Unauthorized("missing bearer token (Authorization: Bearer <token>)")
    given = credentials.credentials.encode()
    match: list[Scope] | None = None
    for token, scopes in settings.auth.tokens.items():
        if hmac.compare_digest(token.encode(), given):
            match = scopes
    if match is None:
        raise Unauthorized("unknown bearer token")
    return Principal(name=credentials.credentials[:4] + "…", scopes=frozenset(match))


def _require(scope: Scope) -> Callable[[Principal], Awaitable[Principal]]:
    async def check(principal: Annotated[Principal, Depends(_principal)]) -> Principal:
        if scope not in principal.scopes:
            raise Forbidden(f"this token lacks the {scope!r} scope")
        return principal

    check.__name__ = f"require_{scope}"
    return check


ReadAccess = Annotated[Principal, Depends(_require("read"))]
DispatchAccess = Annotated[Principal, Depends(_require("dispatch"))]
AdminAccess = Annotated[Principal, Depends(_require("admin"))]
CityName = Annotated[
    str, Path(min_length=1, max_length=64, description="City name, e.g. chengdu.", examples=["chengdu"])
]
