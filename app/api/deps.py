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
    "token_scopes",
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


async def cities_catalog(request: Request) -> CityCatalog:
    """The served cities."""
    return _use_cases(request).cities


async def epoch_service(request: Request) -> EpochService:
    """The epoch use cases."""
    return _use_cases(request).epochs


async def task_service(request: Request) -> TaskService:
    """The task use cases."""
    return _use_cases(request).tasks


async def admin_service(request: Request) -> AdminService:
    """The admin use cases."""
    return _use_cases(request).admin


async def coverage_service(request: Request) -> CoverageService:
    """The coverage use case."""
    return _use_cases(request).coverage


async def readiness_service(request: Request) -> ReadinessService:
    """The readiness use case."""
    return _use_cases(request).readiness


async def fleet_service(request: Request) -> FleetService:
    """The fleet-sizing use cases."""
    return _use_cases(request).fleet


async def app_metrics(request: Request) -> Metrics:
    """The app's metrics."""
    metrics: Metrics = request.app.state.metrics
    return metrics


async def app_settings(request: Request) -> Settings:
    """The app's settings."""
    settings: Settings = request.app.state.settings
    return settings


CitiesDep = Annotated[CityCatalog, Depends(cities_catalog)]
EpochsDep = Annotated[EpochService, Depends(epoch_service)]
TasksDep = Annotated[TaskService, Depends(task_service)]
AdminDep = Annotated[AdminService, Depends(admin_service)]
CoverageDep = Annotated[CoverageService, Depends(coverage_service)]
ReadinessDep = Annotated[ReadinessService, Depends(readiness_service)]
FleetDep = Annotated[FleetService, Depends(fleet_service)]
MetricsDep = Annotated[Metrics, Depends(app_metrics)]
SettingsDep = Annotated[Settings, Depends(app_settings)]


async def request_limits(settings: SettingsDep) -> Limits:
    """Items per request, from the settings."""
    return Limits.from_settings(settings)


LimitsDep = Annotated[Limits, Depends(request_limits)]

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
    match = token_scopes(settings, credentials.credentials)
    if match is None:
        raise Unauthorized("unknown bearer token")
    return Principal(name=credentials.credentials[:4] + "…", scopes=frozenset(match))


def token_scopes(settings: Settings, token: str) -> list[Scope] | None:
    """The scopes of bearer token ``token`` in ``SD_TOKENS`` (None: unknown), compared with every token in
    constant time."""
    given = token.encode()
    match: list[Scope] | None = None
    for known, scopes in settings.auth.tokens.items():
        if hmac.compare_digest(known.encode(), given):
            match = scopes
    return match


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
