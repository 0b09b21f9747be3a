"""The fleet-sizing use cases of the API (docs/FLEET.md): the worker's recommendations and history, a solve
request for the worker, and the worker's status from its heartbeats.

The API never solves: a fleet worker does (``python -m app worker``, or the one ``python -m app run``
embeds on the memory store), and writes a heartbeat to the store every few seconds. A solve request is
queued only when a worker serving the city has been seen within ``stale_s``; otherwise nobody would ever
answer it, and the request is refused (``NoWorker``, a 503) having changed nothing.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from app.errors import NoData, NoWorker
from app.ports import EnqueueResult, FleetRecord, FleetStore, SolveRequest, WorkerBeat
from app.usecases.cities import CityCatalog
from services.city import City

__all__ = ["FleetService", "FleetStatus", "START_WORKER_HINT"]

START_WORKER_HINT = (
    "start one: `python -m app worker` with the API's SD_STORE and SD_REDIS_URL (on the memory store "
    "`python -m app run` runs it inside the service unless SD_WORKER_EMBEDDED=off)"
)


@dataclass(frozen=True, slots=True)
class FleetStatus:
    """Where a city's fleet sizing stands at ``now_s``: the workers' latest beats (newest first; one is
    ``live`` when seen within ``stale_after_s``), the pending solve request and the last solve."""

    city: City
    now_s: float
    stale_after_s: float
    beats: tuple[WorkerBeat, ...]
    pending: SolveRequest | None
    last: FleetRecord | None

    @property
    def live(self) -> tuple[WorkerBeat, ...]:
        """The beats of the workers seen within ``stale_after_s``."""
        return tuple(b for b in self.beats if self.now_s - b.seen_at_s <= self.stale_after_s)


class FleetService:
    """Reads the worker's results and status, queues solve requests (never solves)."""

    def __init__(
        self,
        cities: CityCatalog,
        store: FleetStore,
        *,
        stale_s: float,
        clock: Callable[[], float] = time.time,
    ) -> None:
        """``stale_s``: a worker not seen for longer is gone; ``clock`` is POSIX seconds (heartbeats are)."""
        self.cities = cities
        self.store = store
        self.stale_s = stale_s
        self.clock = clock

    def recommendation(self, name: str) -> tuple[City, FleetRecord]:
        """The city and its current fleet recommendation (``NoData``, a 404, before the first solve)."""
        city = self.cities.get(name)
        record = self.store.current_recommendation(name)
        if record is None:
            raise NoData(
                f"no fleet recommendation for {name!r} yet: the fleet worker publishes one before every "
                "hour of the horizon; POST .../fleet/solve asks for one now (GET .../fleet/status shows "
                "the worker)"
            )
        return city, record

    def recommendation_history(self, name: str, limit: int) -> tuple[City, list[FleetRecord]]:
        """The city and up to ``limit`` of its solves, newest first."""
        city = self.cities.get(name)
        return city, self.store.recommendation_history(name, limit)

    def request_solve(self, name: str, request_id: str, by: str | None) -> tuple[City, EnqueueResult]:
        """Queue a solve of the coming hour for the worker (a pending request is joined, not duplicated);
        ``NoWorker`` when no worker serving the city has been seen within ``stale_s`` (nothing queued)."""
        city = self.cities.get(name)
        now = self.clock()
        beats = self.store.worker_beats(name)
        if not any(now - b.seen_at_s <= self.stale_s for b in beats):
            last = (
                "never" if not beats else f"last seen {now - beats[0].seen_at_s:.0f} s ago ({beats[0].host})"
            )
            raise NoWorker(
                f"no fleet worker serving {name!r} has been seen in the last {self.stale_s:g} s ({last}): "
                f"a queued solve would never run; {START_WORKER_HINT}"
            )
        return city, self.store.enqueue_solve_request(name, SolveRequest(request_id, now, by))

    def status(self, name: str) -> FleetStatus:
        """The workers' beats, the pending request and the last solve of the city."""
        city = self.cities.get(name)
        beats = tuple(self.store.worker_beats(name))
        pending = self.store.pending_solve_request(name)
        history = self.store.recommendation_history(name, 1)
        return FleetStatus(city, self.clock(), self.stale_s, beats, pending, history[0] if history else None)

    def heartbeat_ages(self) -> dict[str, float | None]:
        """Seconds since each served city's newest worker heartbeat (``None``: none kept)."""
        now = self.clock()
        out: dict[str, float | None] = {}
        for name in self.cities.names():
            beats = self.store.worker_beats(name)
            out[name] = None if not beats else max(0.0, now - beats[0].seen_at_s)
        return out
