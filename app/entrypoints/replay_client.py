"""The replay client: a ``services.sim`` dispatcher that asks a running service over HTTP.

The simulator builds each epoch's snapshot; ``HttpDispatcher`` posts it as the platform would (node ids,
RFC 3339 times in the city's zone), turns the response back into core types, and reads tasks and coverage
through the public API at the end. A transport error or a 503 is retried with the *same* epoch id, so a
retry can never count an epoch twice (the service answers a repeated epoch with the stored response).
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TextIO

import httpx
import numpy as np
from numpy.typing import NDArray

from app.usecases.epoch_record import decision_of, task_of
from services.city import City
from services.model import IntervalKey, RiderId, Snapshot, Task, TaskId
from services.rfc3339 import format_time
from services.sim.local import Outcome

__all__ = ["ReplayError", "HttpDispatcher", "service_client"]

_TASK_CHUNK = 500


class ReplayError(RuntimeError):
    """The service refused a request the replay client had to make."""

    def __init__(self, what: str, response: httpx.Response) -> None:
        try:
            detail: Any = response.json()
        except ValueError:
            detail = response.text[:300]
        super().__init__(f"{what}: HTTP {response.status_code} {detail}")
        self.status_code = response.status_code


class HttpDispatcher:
    """Decisions from a service at ``client.base_url`` for city ``name`` (``city`` is the same city, loaded
    locally, to convert node ids and times).

    Parameters
    ----------
    client : an ``httpx.Client`` with the base URL and a bearer token of scopes ``read`` and ``dispatch``.
    name : the city's name on the service.
    city : the city itself (its network must be the one the service serves).
    retries : attempts per request on transport errors and 503s (with back-off).

    After each epoch, ``last_response`` holds the service's response document and ``last_replayed`` whether
    it was the stored answer to an identical earlier post.
    """

    def __init__(self, client: httpx.Client, name: str, city: City, *, retries: int = 5) -> None:
        self.client = client
        self.name = name
        self.city = city
        self.retries = retries
        self._ids = city.network.node_ids
        self._tz = city.horizon.timezone
        self._task_ids: list[TaskId] = []
        self.retried = 0  # requests that needed more than one attempt
        self.last_response: dict[str, Any] | None = None
        self.last_replayed = False

    def _send(self, method: str, url: str, what: str, **kwargs: Any) -> Any:
        return self._request(method, url, what, **kwargs).json()

    def _request(self, method: str, url: str, what: str, **kwargs: Any) -> httpx.Response:
        delay = 0.2
        for attempt in range(1, self.retries + 1):
            try:
                r = self.client.request(method, url, **kwargs)
            except httpx.TransportError:
                if attempt == self.retries:
                    raise
            else:
                if r.status_code != 503:
                    if r.status_code != 200:
                        raise ReplayError(what, r)
                    if attempt > 1:
                        self.retried += 1
                    return r
                if attempt == self.retries:
                    raise ReplayError(what, r)
            time.sleep(delay)
            delay = min(delay * 2, 5.0)
        raise AssertionError("unreachable")

    def _node(self, index: int) -> dict[str, int]:
        return {"node": int(self._ids[index])}

    def _time(self, time_s: float) -> str:
        return format_time(time_s, self._tz)

    def add_tasks(self, tasks: Sequence[Task]) -> None:
        """Register tasks (idempotent per id on the service)."""
        base = f"/v1/cities/{self.name}/tasks"
        for i in range(0, len(tasks), _TASK_CHUNK):
            body = [
                {
                    "id": str(t.id),
                    "location": self._node(t.node),
                    "scheduled_at": self._time(t.scheduled_at_s),
                }
                for t in tasks[i : i + _TASK_CHUNK]
            ]
            self._send("POST", base, "register tasks", json=body)
        self._task_ids.extend(t.id for t in tasks)

    def epoch(self, snapshot: Snapshot) -> Outcome:
        """Post one epoch and convert the decision back to node indices."""
        body = {
            "epoch_id": snapshot.epoch_id,
            "time": self._time(snapshot.time_s),
            "riders": [
                {
                    "id": str(r.id),
                    "origin": self._node(r.origin),
                    "destination": self._node(r.destination),
                    "requested_at": self._time(r.requested_at_s),
                }
                for r in snapshot.riders
            ],
            "taxis": [
                {
                    "id": str(t.id),
                    "location": self._node(t.node),
                    "instrumented": t.instrumented,
                    "status": "vacant" if t.vacant else "busy",
                }
                for t in snapshot.taxis
            ],
        }
        r = self._request("POST", f"/v1/cities/{self.name}/epochs", f"epoch {snapshot.epoch_id}", json=body)
        doc = r.json()
        self.last_response, self.last_replayed = doc, r.headers.get("Idempotent-Replayed") == "true"
        decision = decision_of(self.city, doc)
        expired = tuple(RiderId(r) for r in doc["expired_rider_ids"])
        solve_ms = float(doc["stats"].get("solve_ms", float("nan")))
        return Outcome(decision.rider_matches, decision.task_assignments, expired, solve_ms)

    def tasks(self) -> list[Task]:
        """The tasks this client registered, as the service holds them now."""
        doc = self._send("GET", f"/v1/cities/{self.name}/tasks", "list tasks")
        mine = set(self._task_ids)
        return [task_of(self.city, t) for t in doc["tasks"] if t["id"] in mine]

    def interval_counts(self, k: IntervalKey) -> NDArray[np.int64]:
        """Lambda over all cells of interval ``k``, from the coverage endpoint."""
        label = self.city.horizon.label(k)
        doc = self._send("GET", f"/v1/cities/{self.name}/coverage", "coverage", params={"interval": label})
        arr = np.zeros(self.city.grid.n_cells, dtype=np.int64)
        n_cols = self.city.grid.n_cols
        for c in doc["cells"]:
            col, row = c["cell"]
            arr[row * n_cols + col] = int(c["count"])
        return arr


@contextmanager
def service_client(url: str | None, token: str | None, log: TextIO) -> Iterator[httpx.Client]:
    """A client of the service at ``url`` with bearer ``token``, or, with no ``url``, of one started in this
    process on an in-memory store (announced on ``log``)."""
    if url is not None:
        headers = {"Authorization": f"Bearer {token}"}
        with httpx.Client(base_url=url.rstrip("/"), headers=headers, timeout=300.0) as client:
            yield client
        return
    from app.entrypoints.serve import serve_in_thread

    with serve_in_thread() as (local_url, local_token):
        print(f"started the service in-process at {local_url} (memory store)", file=log, flush=True)
        with service_client(local_url, local_token, log) as client:
            yield client
