"""The fleet-sizing use cases of the API (docs/FLEET.md): the worker's recommendations and history, a solve
request for the worker, and the worker's status from its heartbeats.

The API never solves: a fleet worker does (``python -m app worker``, or the one ``python -m app run``
embeds on the memory store), and writes a heartbeat to the store every few seconds. A solve request is
queued only when the city has the history it is sized on (else ``InsufficientHistory``, a 409) and a
worker serving the city has been seen within ``stale_s`` (else ``NoWorker``, a 503): otherwise nobody
would ever answer it. A refused request changes nothing.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from app.errors import InsufficientHistory, NoData, NoWorker
from app.ports import EnqueueResult, FleetRecord, SolveRequest, WorkerBeat, WorkerStore
from app.usecases.cities import CityCatalog
from app.usecases.fleet_history import FleetHistory, HistoryState, SizingConfig
from services.city import City

__all__ = ["FleetService", "FleetStatus", "START_WORKER_HINT"]

START_WORKER_HINT = (
    "start one: `python -m app worker` with the API's SD_STORE and SD_REDIS_URL (on the memory store "
    "`python -m app run` runs it inside the service unless SD_WORKER_EMBEDDED=off)"
)


@dataclass(frozen=True, slots=True)
class FleetStatus:
    """Where a city's fleet sizing stands at ``now_s``: the workers' latest beats (newest first; one is
    ``live`` when seen within ``stale_after_s``), the pending solve request, the last solve and the
    history a solve today would have (``history``; ``synthetic`` for a demo city sized on its generator's
    days until then)."""

    city: City
    now_s: float
    stale_after_s: float
    beats: tuple[WorkerBeat, ...]
    pending: SolveRequest | None
    last: FleetRecord | None
    history: HistoryState

    @property
    def live(self) -> tuple[WorkerBeat, ...]:
        """The beats of the workers seen within ``stale_after_s``."""
        return tuple(b for b in self.beats if self.now_s - b.seen_at_s <= self.stale_after_s)


class FleetService:
    """Reads the worker's results and status, queues solve requests (never solves)."""

    def __init__(
        self,
        cities: CityCatalog,
        store: WorkerStore,
        *,
        stale_s: float,
        sizing: SizingConfig,
        clock: Callable[[], float] = time.time,
    ) -> None:
        """``stale_s``: a worker not seen for longer is gone; ``sizing`` the worker's settings (M and the
        look-back of a city without its own); ``clock`` is POSIX seconds (heartbeats are)."""
        self.cities = cities
        self.store = store
        self.stale_s = stale_s
        self.history = FleetHistory(store, sizing)
        self.clock = clock

    def history_state(self, city: City) -> HistoryState:
        """How many of the M days a solve now needs the city has recorded (the days before the date of the
        hour it would be for: the coming hour of the horizon)."""
        hz = city.horizon
        return self.history.state(city, hz.local_start(hz.coming_interval(self.clock())).date())

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
        ``InsufficientHistory`` when the city waits for the M days it is sized on, ``NoWorker`` when no
        worker serving the city has been seen within ``stale_s`` (nothing queued either way)."""
        city = self.cities.get(name)
        history = self.history_state(city)
        if not history.enough and not city.fleet.synthetic_history:
            raise InsufficientHistory(
                f"{name!r} cannot be sized yet: {history.describe()}",
                days=history.days,
                needed=history.needed,
                first_solve_on=history.first_solve_on.isoformat(),
            )
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
        last = self.store.recommendation_history(name, 1)
        return FleetStatus(
            city,
            self.clock(),
            self.stale_s,
            beats,
            pending,
            last[0] if last else None,
            self.history_state(city),
        )

    def heartbeat_ages(self) -> dict[str, float | None]:
        """Seconds since each served city's newest worker heartbeat (``None``: none kept)."""
        now = self.clock()
        out: dict[str, float | None] = {}
        for name in self.cities.names():
            beats = self.store.worker_beats(name)
            out[name] = None if not beats else max(0.0, now - beats[0].seen_at_s)
        return out
