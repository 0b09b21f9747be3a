"""Tasks as the stores keep them (``app.adapters.codec``): compact, key-sorted JSON that reads back as the
same task, that also reads the text ``json.dumps`` wrote for the same document, and that refuses a number
JSON cannot hold."""

from __future__ import annotations

import json
import math

import pytest

from app.adapters.codec import task_from_json, task_to_json
from services.model import Task, TaskId, TaxiId

TASKS = [
    Task(TaskId("p0"), 3, 1795392000.0),
    Task(TaskId('q"\\/é'), 0, 1e16, "completed", 1e-7, TaxiId("t\U0001f695"), "passive", (104.06, 30.67)),
    Task(TaskId("p2"), 2**40, 0.1 + 0.2, "assigned", None, TaxiId("t1"), "active", (-0.0, 5e-324)),
    Task(TaskId("p3"), 7, 1795392000.125, "expired", 1795395600.5),
]


def _json_dumps_text(task: Task) -> str:
    """The text ``json.dumps`` writes for the task's document (keys sorted, compact)."""
    doc = json.loads(task_to_json(task))
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)


@pytest.mark.parametrize("task", TASKS, ids=lambda t: str(t.id))
def test_a_task_reads_back_as_itself(task: Task) -> None:
    text = task_to_json(task)
    assert task_from_json(text) == task
    assert list(json.loads(text)) == sorted(json.loads(text))  # keys sorted
    assert ", " not in text and '": ' not in text  # compact
    assert task_from_json(_json_dumps_text(task)) == task


@pytest.mark.parametrize(
    "bad",
    [
        Task(TaskId("n"), 1, math.nan),
        Task(TaskId("i"), 1, 0.0, "completed", math.inf),
        Task(TaskId("l"), 1, 0.0, location=(104.0, -math.inf)),
    ],
)
def test_a_number_json_cannot_hold_is_refused(bad: Task) -> None:
    with pytest.raises(ValueError, match="not a finite number"):
        task_to_json(bad)
