"""Write routes: register monitoring tasks and post decision epochs (scope `dispatch`)."""

from __future__ import annotations

import time

from fastapi import APIRouter, Response

from app.api.bodies import RawBody, TasksBody, epoch_post, request_body
from app.api.deps import CitiesDep, CityName, DispatchAccess, EpochsDep, LimitsDep, MetricsDep, TasksDep
from app.api.inputs import epoch_command, tasks_of
from app.api.responses import WRITE_ERRORS
from app.errors import ServiceError
from app.schemas.decision import EpochIn, EpochOut
from app.schemas.tasks import TasksPutOut

__all__ = ["router"]

router = APIRouter(prefix="/v1/cities", tags=["dispatch"], responses=WRITE_ERRORS)


@router.post(
    "/{city}/tasks",
    response_model=TasksPutOut,
    summary="Register monitoring tasks",
    openapi_extra=request_body("TasksIn"),
)
def post_tasks(
    city: CityName,
    _: DispatchAccess,
    tasks: TasksBody,
    catalog: CitiesDep,
    registered: TasksDep,
) -> TasksPutOut:
    """Register tasks: an id already stored with the same content is unchanged, with other content 409."""
    served = catalog.get(city)  # the one look-up: the tasks' node indices and their registration use it
    return TasksPutOut.of(registered.put_tasks(served, tasks_of(served, tasks)))


@router.post(
    "/{city}/epochs",
    response_model=EpochOut,
    summary="Solve and commit one decision epoch",
    responses={
        200: {
            "description": "The decision; a replay of a committed epoch returns the stored decision.",
            "headers": {
                "Idempotent-Replayed": {
                    "description": "`true` when this is the stored response of an earlier identical post.",
                    "schema": {"type": "string", "enum": ["true"]},
                }
            },
        }
    },
    openapi_extra=request_body(EpochIn),
)
def post_epoch(
    city: CityName,
    _: DispatchAccess,
    raw: RawBody,
    catalog: CitiesDep,
    epochs: EpochsDep,
    metrics: MetricsDep,
    limits: LimitsDep,
) -> Response:
    """Match riders (Steps 1-2), route idle instrumented taxis to POIs (Step 3), commit exactly once."""
    # the whole exchange, body to response, holds the foreground (app.api.foreground): the embedded
    # worker's runs stay stopped throughout (docs/FLEET.md)
    epoch = epoch_post(raw, limits)  # on this threadpool thread, before anything is counted
    started = time.perf_counter()
    try:
        served = catalog.get(city)  # the one look-up: the epoch's node indices and its solve use it
        command = epoch_command(served, epoch.body, epoch.taxis, epoch.riders)
        outcome = epochs.submit_epoch(served, command)
    except ServiceError as err:  # StoreUnavailable included: its kind is store_unavailable
        metrics.epochs.labels(outcome=err.kind).inc()
        raise
    except Exception:
        metrics.epochs.labels(outcome="error").inc()
        raise
    finally:
        metrics.epoch_latency.observe(time.perf_counter() - started)
    headers: dict[str, str] = {}
    if outcome.replayed:
        metrics.epochs.labels(outcome="replayed").inc()
        headers["Idempotent-Replayed"] = "true"
    else:
        metrics.epochs.labels(outcome="committed").inc()
        for step, n in outcome.matches_by_step.items():
            metrics.matches.labels(step=str(step)).inc(n)
        metrics.task_assignments.inc(outcome.n_task_assignments)
        if outcome.attempts > 1:
            metrics.commit_retries.inc(outcome.attempts - 1)
    return Response(content=outcome.response_json, media_type="application/json", headers=headers)
