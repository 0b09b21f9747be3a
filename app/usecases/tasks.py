"""The task use cases: the platform registers the POIs that need monitoring (idempotent per id) and reads
them back; Step 3 of every epoch assigns the open ones (``app.usecases.epochs``)."""

from __future__ import annotations

from collections.abc import Sequence

from app.errors import FieldIssue, TaskConflict
from app.ports import PutTasksResult, TaskStore
from app.usecases.cities import CityCatalog
from services.city import City
from services.model import Task

__all__ = ["TaskService"]


class TaskService:
    """Registers and lists a city's tasks."""

    def __init__(self, cities: CityCatalog, store: TaskStore) -> None:
        self.cities = cities
        self.store = store

    def put_tasks(self, city: City, tasks: Sequence[Task]) -> PutTasksResult:
        """Register tasks of ``city``, idempotent per id (409 naming the conflicting ids' positions; nothing
        written). ``city`` is the served city the caller resolved the tasks' node indices against
        (``CityCatalog.get``): it is not looked up again."""
        result = self.store.put_tasks(city.name, tasks)
        if result.conflicts:
            index = {t.id: i for i, t in enumerate(tasks)}
            raise TaskConflict(
                "tasks exist with different content: " + ", ".join(map(str, result.conflicts)),
                [
                    FieldIssue(f"[{index[c]}].id", f"task {c!r} exists with different content")
                    for c in result.conflicts
                ],
            )
        return result

    def list_tasks(self, name: str) -> tuple[City, list[Task]]:
        """The city and its tasks (open ones, and finished ones within the retention), in scheduled order."""
        city = self.cities.get(name)
        return city, sorted(self.store.list_tasks(name), key=lambda t: (t.scheduled_at_s, t.id))
