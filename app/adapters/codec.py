"""Serialization shared by the store adapters: tasks and fleet records as JSON, registration comparison,
demand days."""

from __future__ import annotations

import json
import math
import secrets
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import orjson

from app.ports import FleetRecord, PutTasksResult, SolveProgress, SolveRequest, Waiting, WorkerBeat
from services.model import Task, TaskId, TaxiId

__all__ = [
    "task_to_json",
    "task_from_json",
    "same_registration",
    "classify_tasks",
    "TaskClassification",
    "format_time",
    "fleet_record_to_json",
    "fleet_record_from_json",
    "solve_request_to_json",
    "solve_request_from_json",
    "check_fleet_record",
    "new_lock_token",
    "worker_beat_to_json",
    "worker_beat_from_json",
]


def format_time(time_s: float) -> str:
    """Exact text form of a POSIX time (``repr`` round-trips a float)."""
    return repr(float(time_s))


def task_to_json(task: Task) -> str:
    """Compact, key-sorted JSON of a task (orjson: an epoch on Redis writes and reads dozens of them; a
    time or position that is not finite is refused, as JSON has no such number)."""
    doc: dict[str, Any] = {
        "id": str(task.id),
        "node": int(task.node),
        "scheduled_at_s": float(task.scheduled_at_s),
        "status": task.status,
        "completed_at_s": None if task.completed_at_s is None else float(task.completed_at_s),
        "taxi_id": None if task.taxi_id is None else str(task.taxi_id),
        "mode": task.mode,
        "location": None if task.location is None else [float(task.location[0]), float(task.location[1])],
    }
    if not all(map(math.isfinite, _times(task))):
        raise ValueError(f"task {task.id!r}: a time or position that is not a finite number")
    return orjson.dumps(doc, option=orjson.OPT_SORT_KEYS).decode()


def _times(task: Task) -> tuple[float, ...]:
    return (
        float(task.scheduled_at_s),
        0.0 if task.completed_at_s is None else float(task.completed_at_s),
        *(() if task.location is None else (float(task.location[0]), float(task.location[1]))),
    )


def task_from_json(text: str) -> Task:
    """Inverse of ``task_to_json`` (it reads ``json.dumps``'s text of the same document too)."""
    doc = orjson.loads(text)
    location = doc.get("location")
    completed = doc.get("completed_at_s")
    taxi = doc.get("taxi_id")
    return Task(
        id=TaskId(doc["id"]),
        node=int(doc["node"]),
        scheduled_at_s=float(doc["scheduled_at_s"]),
        status=doc.get("status", "pending"),
        completed_at_s=None if completed is None else float(completed),
        taxi_id=None if taxi is None else TaxiId(taxi),
        mode=doc.get("mode"),
        location=None if location is None else (float(location[0]), float(location[1])),
    )


def same_registration(a: Task, b: Task) -> bool:
    """Whether two tasks were registered alike (id, node, scheduled time, location); lifecycle is ignored."""
    return (
        a.id == b.id
        and a.node == b.node
        and float(a.scheduled_at_s) == float(b.scheduled_at_s)
        and a.location == b.location
    )


@dataclass(frozen=True, slots=True)
class TaskClassification:
    """Outcome of comparing posted tasks with stored ones: the result, and what to write if no conflict."""

    result: PutTasksResult
    to_write: dict[TaskId, Task] = field(default_factory=dict)


def classify_tasks(lookup: Callable[[TaskId], Task | None], tasks: Sequence[Task]) -> TaskClassification:
    """Sort posted tasks into created / unchanged / conflicts; a repeated id is compared with its first."""
    created: list[TaskId] = []
    unchanged: list[TaskId] = []
    conflicts: list[TaskId] = []
    pending: dict[TaskId, Task] = {}
    for task in tasks:
        existing = pending.get(task.id) or lookup(task.id)
        if existing is None:
            pending[task.id] = task
            created.append(task.id)
        elif same_registration(existing, task):
            if task.id not in pending and task.id not in unchanged:
                unchanged.append(task.id)
        elif task.id not in conflicts:
            conflicts.append(task.id)
    if conflicts:
        return TaskClassification(PutTasksResult(conflicts=conflicts))
    return TaskClassification(PutTasksResult(created=created, unchanged=unchanged), pending)


def fleet_record_to_json(record: FleetRecord) -> str:
    """Compact, key-sorted JSON of a fleet-sizing record (the body travels as a string inside it)."""
    doc: dict[str, Any] = {
        "status": record.status,
        "computed_at_s": float(record.computed_at_s),
        "interval": int(record.interval),
        "version": None if record.version is None else int(record.version),
        "body": record.body_json,
        "reason": record.reason,
        "request_id": record.request_id,
    }
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)


def fleet_record_from_json(text: str) -> FleetRecord:
    """Inverse of ``fleet_record_to_json``."""
    doc = json.loads(text)
    version = doc.get("version")
    return FleetRecord(
        status=doc["status"],
        computed_at_s=float(doc["computed_at_s"]),
        interval=int(doc["interval"]),
        version=None if version is None else int(version),
        body_json=doc.get("body"),
        reason=doc.get("reason"),
        request_id=doc.get("request_id"),
    )


def solve_request_to_json(request: SolveRequest) -> str:
    """Compact JSON of a queued solve request."""
    doc = {"id": request.request_id, "at_s": float(request.requested_at_s), "by": request.requested_by}
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)


def solve_request_from_json(text: str) -> SolveRequest:
    """Inverse of ``solve_request_to_json``."""
    doc = json.loads(text)
    return SolveRequest(str(doc["id"]), float(doc["at_s"]), doc.get("by"))


def check_fleet_record(record: FleetRecord, status: str, history_limit: int) -> None:
    """``ValueError`` unless ``record`` has ``status`` (and a version >= 1 and a body when published) and
    ``history_limit`` is at least 1."""
    if record.status != status:
        raise ValueError(f"expected a {status!r} record, got {record.status!r}")
    if status == "published" and (record.version is None or record.version < 1 or record.body_json is None):
        raise ValueError("a published record needs a version >= 1 and a body")
    if history_limit < 1:
        raise ValueError(f"history_limit must be at least 1, got {history_limit}")


def new_lock_token() -> str:
    """A random lock token (only its holder can release the lock)."""
    return secrets.token_hex(16)


def worker_beat_to_json(beat: WorkerBeat) -> str:
    """Compact, key-sorted JSON of a worker's heartbeat."""
    p = beat.solving
    solving: dict[str, Any] | None = None
    if p is not None:
        solving = {
            "interval": int(p.interval),
            "trigger": p.trigger,
            "request_id": p.request_id,
            "started_at_s": float(p.started_at_s),
            "runs": [p.runs_total, p.runs_done, p.runs_cached, p.runs_running, p.runs_failed],
        }
    doc: dict[str, Any] = {
        "id": beat.worker_id,
        "seen_at_s": float(beat.seen_at_s),
        "started_at_s": float(beat.started_at_s),
        "host": beat.host,
        "pid": int(beat.pid),
        "embedded": bool(beat.embedded),
        "poll_s": float(beat.poll_s),
        "solving": solving,
        "next_interval": None if beat.next_interval is None else int(beat.next_interval),
        "next_due_at_s": None if beat.next_due_at_s is None else float(beat.next_due_at_s),
    }
    if beat.waiting is not None:
        w = beat.waiting
        doc["waiting"] = {"kind": w.kind, "reason": w.reason, "since_s": float(w.since_s)}
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)


def worker_beat_from_json(text: str) -> WorkerBeat:
    """Inverse of ``worker_beat_to_json``."""
    doc = json.loads(text)
    s = doc.get("solving")
    solving = None
    if s is not None:
        total, done, cached, running, failed = (int(v) for v in s["runs"])
        solving = SolveProgress(
            int(s["interval"]),
            s["trigger"],
            s.get("request_id"),
            float(s["started_at_s"]),
            total,
            done,
            cached,
            running,
            failed,
        )
    nxt, due = doc.get("next_interval"), doc.get("next_due_at_s")
    w = doc.get("waiting")
    waiting = None if w is None else Waiting(str(w["kind"]), str(w["reason"]), float(w["since_s"]))
    return WorkerBeat(
        worker_id=str(doc["id"]),
        seen_at_s=float(doc["seen_at_s"]),
        started_at_s=float(doc["started_at_s"]),
        host=str(doc["host"]),
        pid=int(doc["pid"]),
        embedded=bool(doc["embedded"]),
        poll_s=float(doc["poll_s"]),
        solving=solving,
        next_interval=None if nxt is None else int(nxt),
        next_due_at_s=None if due is None else float(due),
        waiting=waiting,
    )
