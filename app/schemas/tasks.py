"""Models of the task routes: registering (``app.api.dispatch``) and listing (``app.api.cities``) POIs."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

from pydantic import Field

from app.ports import PutTasksResult
from app.schemas.common import Identifier, LocationIn, ResponseModel, Rfc3339, TimedRequest, format_time
from services.city import City
from services.model import Task, TaskId, TaxiId
from services.rfc3339 import parse_rfc3339

__all__ = ["TaskIn", "TaskOut", "TasksOut", "TasksPutOut", "task_doc", "task_of"]


class TaskIn(TimedRequest):
    """A monitoring task: a POI and the time from which it is open."""

    id: Identifier
    location: LocationIn
    scheduled_at: Rfc3339


class TaskOut(ResponseModel):
    """A monitoring task and its lifecycle."""

    id: str
    node: int = Field(description="External id of the POI node.")
    status: Literal["pending", "assigned", "completed", "expired"]
    scheduled_at: str
    completed_at: str | None = Field(description="When the POI is (or will be, if assigned) reached.")
    taxi_id: str | None
    mode: Literal["passive", "active"] | None

    @classmethod
    def of(cls, city: City, task: Task) -> TaskOut:
        """Render a core task with external node ids and local times."""
        return cls.model_validate(task_doc(city, task))


def task_doc(city: City, task: Task) -> dict[str, Any]:
    """A core task as a ``TaskOut`` document (same fields, same order), not validated again."""
    tz = city.horizon.timezone
    return {
        "id": str(task.id),
        "node": int(city.network.node_ids[task.node]),
        "status": task.status,
        "scheduled_at": format_time(task.scheduled_at_s, tz),
        "completed_at": None if task.completed_at_s is None else format_time(task.completed_at_s, tz),
        "taxi_id": None if task.taxi_id is None else str(task.taxi_id),
        "mode": task.mode,
    }


def task_of(city: City, doc: Mapping[str, Any]) -> Task:
    """The core task a ``TaskOut`` document describes (node index, POSIX times); the inverse of ``of``."""
    done = doc["completed_at"]
    return Task(
        id=TaskId(doc["id"]),
        node=city.network.index_of(doc["node"]),
        scheduled_at_s=parse_rfc3339(doc["scheduled_at"]).timestamp(),
        status=doc["status"],
        completed_at_s=None if done is None else parse_rfc3339(done).timestamp(),
        taxi_id=None if doc["taxi_id"] is None else TaxiId(doc["taxi_id"]),
        mode=doc["mode"],
    )


class TasksOut(ResponseModel):
    """All tasks of a city."""

    tasks: list[TaskOut]


class TasksPutOut(ResponseModel):
    """Outcome of registering tasks (idempotent per id)."""

    created: list[str]
    unchanged: list[str]

    @classmethod
    def of(cls, result: PutTasksResult) -> TasksPutOut:
        """The ids registered now and those already registered with the same content."""
        return cls(created=[str(t) for t in result.created], unchanged=[str(t) for t in result.unchanged])
