"""Operational routes: liveness, readiness and Prometheus metrics (no auth)."""

from __future__ import annotations

import logging

from fastapi import APIRouter, Response
from starlette.concurrency import run_in_threadpool

from app.api.deps import FleetDep, MetricsDep, ReadinessDep, SettingsDep
from app.api.responses import errors
from app.metrics import CONTENT_TYPE
from app.schemas.ops import HealthOut, ReadyOut

__all__ = ["router"]

router = APIRouter(tags=["ops"])

log = logging.getLogger(__name__)


@router.get("/healthz", response_model=HealthOut, summary="The process is up")
async def healthz() -> HealthOut:
    """Liveness: answers as long as the process serves requests. It touches neither the store nor the
    threadpool (``async``), so a frozen store or busy worker threads never fail the probe."""
    return HealthOut(status="ok")


@router.get(
    "/readyz",
    response_model=ReadyOut,
    summary="Warmed up, store reachable and cities loaded",
    responses=errors(503),
)
def readyz(readiness: ReadinessDep, settings: SettingsDep) -> ReadyOut:
    """Readiness: start-up's warm-up has finished (every city loaded and the routing kernels compiled or
    read from their cache), the store answers a ping and every city loads (503 otherwise; the error says
    only "store unreachable", never where the store is)."""
    return ReadyOut(status="ready", store=settings.store.kind, cities=readiness.ready())


@router.get(
    "/metrics",
    summary="Prometheus metrics",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE.split(";")[0]: {"schema": {"type": "string"}}}}},
)
async def metrics(m: MetricsDep, fleet: FleetDep) -> Response:
    """Prometheus text exposition of this instance's metrics. The fleet worker's heartbeat age per city is
    read from the store (off the event loop); when the store cannot answer, those gauges keep their last
    values and the rest is served all the same."""
    try:
        m.set_heartbeat_ages(await run_in_threadpool(fleet.heartbeat_ages))
    except Exception as exc:  # noqa: BLE001 - a scrape never fails for the store's sake
        log.warning("metrics: worker heartbeats unreadable: %s", exc)
    return Response(content=m.render(), media_type=CONTENT_TYPE)
