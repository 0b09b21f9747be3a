"""Models of the task routes: registering (``app.api.writes``) and listing (``app.api.cities``) POIs."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from app.ports import PutTasksResult
from app.schemas.common import Identifier, LocationIn, ResponseModel, Rfc3339, TimedRequest
from app.usecases.epoch_record import task_doc
from services.city import City
from services.model import Task

__all__ = ["TaskIn", "TaskOut", "TasksOut", "TasksPutOut"]


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
