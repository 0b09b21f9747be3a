"""The epoch's record: a posted epoch as the use case takes it, its decided result, and the document that
records it (external node ids, local times), written once when the epoch commits, stored with it, answered
to the post and to every replay and read of it (``GET /epochs/{id}``), and read back into core types here.
``app.schemas.decision.EpochOut`` describes the same document (its fields in the same order)."""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from itertools import chain
from typing import Any, Generic, TypeVar, cast

import numpy as np
import orjson

from services.city import City
from services.model import (
    Decision,
    IntervalKey,
    RiderId,
    RiderMatch,
    Snapshot,
    Task,
    TaskAssignment,
    TaskId,
    TaxiId,
)
from services.network.network import Network
from services.rfc3339 import format_time, parse_rfc3339

T = TypeVar("T")

__all__ = [
    "EpochCommand",
    "EpochResult",
    "EpochRenderer",
    "StoredDecision",
    "EpochReader",
    "external_ids",
    "node_index",
    "task_doc",
    "task_of",
    "epoch_doc",
    "render_epoch",
    "decision_of",
    "read_epoch",
]


@dataclass(frozen=True, slots=True)
class EpochCommand:
    """One posted epoch, validated and resolved to node indices at the edge (``app.api.inputs``).

    ``body_hash`` is the sha256 of the request's canonical JSON (``app.schemas.decision.body_hash``, computed
    by the API from the validated request model). It is stored with the commit: a later post of the same
    epoch id is a replay only if its hash is equal, so its definition never changes. ``time_text`` is the
    epoch time as posted (RFC 3339 with the client's offset), echoed in the response and the recorded demand.
    """

    snapshot: Snapshot
    body_hash: str
    time_text: str


@dataclass(frozen=True, slots=True)
class EpochResult:
    """A decided epoch, before its commit: what its record shows (``epoch_doc``).

    ``interval`` is the epoch's own sensing interval; ``gamma_before`` and ``gamma_after`` are Gamma over
    that day's horizon intervals at the epoch's start and with its visits counted; ``attempts`` counts the
    solves (a lost commit race solves again).
    """

    city: City
    epoch: EpochCommand
    decision: Decision
    interval: IntervalKey
    solve_ms: float
    attempts: int
    gamma_before: float
    gamma_after: float


EpochRenderer = Callable[[EpochResult], str]
"""The response document of a decided epoch, committed with it and returned verbatim to replays."""


@dataclass(frozen=True, slots=True)
class StoredDecision:
    """A committed epoch's decision read back from its stored response document, in core types.

    ``trip_time_s`` of a match and ``kappa`` of an assignment are NaN in a document stored before responses
    carried them; the riders' and routes' ``path`` are node indices again.
    """

    epoch_id: str
    time_s: float
    rider_matches: tuple[RiderMatch, ...]
    task_assignments: tuple[TaskAssignment, ...]
    tasks_completed: tuple[Task, ...]


EpochReader = Callable[[City, str], StoredDecision]
"""The decision inside a stored response document (the inverse of an ``EpochRenderer``)."""


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


class _PerNetwork(Generic[T]):
    """A value made from a network, kept for the few most recent networks: each entry holds its network, so a
    value is never taken for another network's while it is kept (``id`` may be reused once it is gone).
    Safe on the threadpool, where epochs are resolved and responses rendered."""

    def __init__(self, make: Callable[[Network], T], keep: int = 8) -> None:
        self._make = make
        self._keep = keep
        self._kept: dict[int, tuple[Network, T]] = {}
        self._lock = threading.Lock()

    def __call__(self, city: City) -> T:
        net = city.network
        with self._lock:
            hit = self._kept.get(id(net))
            if hit is None or hit[0] is not net:
                if len(self._kept) >= self._keep:
                    self._kept.pop(next(iter(self._kept)))
                hit = self._kept[id(net)] = (net, self._make(net))
            return hit[1]


_EXTERNAL_IDS = _PerNetwork(lambda net: cast(list[int], net.node_ids.tolist()))
_NODE_INDEX = _PerNetwork(lambda net: dict(zip(net.node_ids.tolist(), range(net.n_nodes), strict=True)))


def external_ids(city: City) -> list[int]:
    """The city's external node ids as a list of ints (``_PerNetwork``)."""
    return _EXTERNAL_IDS(city)


def node_index(city: City) -> dict[int, int]:
    """The city's node indices by external node id (``_PerNetwork``), for a plain look-up per node where
    ``Network.index_of`` is a method call per node."""
    return _NODE_INDEX(city)


def _ext_paths(city: City, paths: Sequence[tuple[int, ...]]) -> list[list[int]]:
    """External node ids along each path."""
    at = external_ids(city).__getitem__
    return [list(map(at, path)) for path in paths]


def _cells_of(routes: Sequence[tuple[tuple[int, int], ...]]) -> list[list[tuple[int, int]]]:
    """Each route's (col, row) cells as ints: as they are when they already are pairs of ints (one look at
    all of them), converted one by one otherwise."""
    cells = list(chain.from_iterable(routes))
    if set(map(len, cells)) <= {2} and set(map(type, chain.from_iterable(cells))) <= {int}:
        return [list(route) for route in routes]
    return [[(int(c), int(r)) for c, r in route] for route in routes]


def _match_doc(m: RiderMatch, path: list[int], cells: list[tuple[int, int]]) -> dict[str, Any]:
    """A core match as a ``RiderMatchOut`` document (same fields, same order)."""
    return {
        "step": int(m.step),
        "taxi_id": str(m.taxi_id),
        "rider_id": str(m.rider_id),
        "pickup_m": float(m.pickup_m),
        "wait_s": float(m.wait_s),
        "trip_m": float(m.trip_m),
        "trip_time_s": float(m.trip_time_s),
        "sensing_gain": float(m.sensing_gain),
        "path": path,
        "cells": cells,
    }


def _assignment_doc(a: TaskAssignment, path: list[int], cells: list[tuple[int, int]]) -> dict[str, Any]:
    """A core assignment as a ``TaskAssignmentOut`` document (same fields, same order)."""
    return {
        "taxi_id": str(a.taxi_id),
        "task_id": str(a.task_id),
        "path": path,
        "cells": cells,
        "length_m": float(a.length_m),
        "travel_time_s": float(a.travel_time_s),
        "sensing_gain": float(a.sensing_gain),
        "efficiency": float(a.efficiency),
        "cost_cny": float(a.cost_cny),
        "kappa": float(a.kappa),
    }


def epoch_doc(result: EpochResult) -> dict[str, Any]:
    """A decided epoch as an ``EpochOut`` document of plain JSON values (external node ids, local times),
    with the model's fields in the model's order: ``EpochOut.model_validate`` keeps it as it is, so its
    JSON is byte for byte ``EpochOut.of(result).model_dump_json()`` (tests/api/test_render.py)."""
    city, decision, snapshot = result.city, result.decision, result.epoch.snapshot
    matches, routes = decision.rider_matches, decision.task_assignments
    stats = _core_stats(decision)  # decide's own diagnostics, its counts of matches per step among them
    stats.update(
        {
            "task_assignments": len(decision.task_assignments),
            "tasks_completed": len(decision.tasks_completed),
            "riders": len(snapshot.riders),
            "taxis": len(snapshot.taxis),
            "interval": city.horizon.label(result.interval),
            "interval_key": int(result.interval),
            "in_horizon": int(city.horizon.in_horizon(result.interval)),
            "solve_ms": round(float(result.solve_ms), 3),
            "attempts": int(result.attempts),
            "visits": len(decision.visits),
            "gamma": float(result.gamma_after),
            "gamma_gain": float(result.gamma_after - result.gamma_before),
        }
    )
    return {
        "epoch_id": str(snapshot.epoch_id),
        "time": str(result.epoch.time_text),
        "rider_matches": list(
            map(
                _match_doc,
                matches,
                _ext_paths(city, [m.path for m in matches]),
                _cells_of([m.cells for m in matches]),
            )
        ),
        "task_assignments": list(
            map(
                _assignment_doc,
                routes,
                _ext_paths(city, [a.path for a in routes]),
                _cells_of([a.cells for a in routes]),
            )
        ),
        "tasks_completed": [task_doc(city, t) for t in decision.tasks_completed],
        "unmatched_rider_ids": [str(r) for r in decision.unmatched_rider_ids],
        "expired_rider_ids": [str(r) for r in decision.expired_rider_ids],
        "stats": stats,
    }


def _core_stats(decision: Decision) -> dict[str, float | int | str]:
    """The solver's diagnostics as JSON values (booleans as 0/1; NaN and infinities left out)."""
    stats: dict[str, float | int | str] = {}
    for key, value in decision.stats.items():
        v: Any = value
        if isinstance(v, bool | np.bool_ | int | np.integer):
            stats[key] = int(v)
        elif isinstance(v, float | np.floating):
            if math.isfinite(v):  # JSON has no NaN or infinity
                stats[key] = float(v)
        elif isinstance(v, str):
            stats[key] = str(v)
    return stats


def render_epoch(result: EpochResult) -> str:
    """The response document of a decided epoch (``EpochService``'s renderer): ``epoch_doc`` encoded once by
    orjson, without validating the values it was built from a second time. orjson writes what pydantic's
    JSON encoder writes for these values (shortest round-trip floats, UTF-8 text, NaN and infinities as
    ``null``), about three times as fast (tests/api/test_render.py)."""
    return orjson.dumps(epoch_doc(result)).decode()


def decision_of(city: City, doc: Mapping[str, Any]) -> StoredDecision:
    """The decision an ``EpochOut`` document holds, in core types (node indices, POSIX times); the inverse
    of ``EpochOut.of``. A match's ``trip_time_s`` and an assignment's ``kappa`` are NaN in a document written
    before responses carried them."""
    index = city.network.index_of

    def path(ids: list[int]) -> tuple[int, ...]:
        return tuple(index(v) for v in ids)

    def cells(pairs: list[list[int]]) -> tuple[tuple[int, int], ...]:
        return tuple((int(c), int(r)) for c, r in pairs)

    matches = tuple(
        RiderMatch(
            step=m["step"],
            taxi_id=TaxiId(m["taxi_id"]),
            rider_id=RiderId(m["rider_id"]),
            pickup_m=float(m["pickup_m"]),
            wait_s=float(m["wait_s"]),
            trip_m=float(m["trip_m"]),
            trip_time_s=float(m.get("trip_time_s", math.nan)),
            sensing_gain=float(m["sensing_gain"]),
            path=path(m["path"]),
            cells=cells(m["cells"]),
        )
        for m in doc["rider_matches"]
    )
    routes = tuple(
        TaskAssignment(
            taxi_id=TaxiId(a["taxi_id"]),
            task_id=TaskId(a["task_id"]),
            path=path(a["path"]),
            cells=cells(a["cells"]),
            length_m=float(a["length_m"]),
            travel_time_s=float(a["travel_time_s"]),
            sensing_gain=float(a["sensing_gain"]),
            efficiency=float(a["efficiency"]),
            cost_cny=float(a["cost_cny"]),
            kappa=_number(a.get("kappa")),
        )
        for a in doc["task_assignments"]
    )
    completed = tuple(task_of(city, t) for t in doc["tasks_completed"])
    time_s = parse_rfc3339(doc["time"]).timestamp()
    return StoredDecision(doc["epoch_id"], time_s, matches, routes, completed)


def _number(value: float | None) -> float:
    """A float the document holds; NaN for one it does not (absent or null)."""
    return math.nan if value is None else float(value)


def read_epoch(city: City, response_json: str) -> StoredDecision:
    """The decision inside a stored response document (``EpochService``'s reader)."""
    return decision_of(city, json.loads(response_json))
