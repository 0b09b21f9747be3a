"""The worker's heartbeat (docs/FLEET.md, "Heartbeat and status"): what a running worker is doing, written to
the store every few seconds for every city it serves.

``WorkerStatus`` holds the solve in progress (with its runs, fed by the runner's progress callback) and each
city's next scheduled solve; ``Heartbeat`` is a thread that writes ``WorkerStatus.beat`` to the store every
``interval_s`` and at once when a solve starts, ends or finishes a run. The API reads the beats:
``POST .../fleet/solve`` is refused when no worker serving the city has been seen recently, and
``GET .../fleet/status`` shows them.
"""

from __future__ import annotations

import logging
import os
import secrets
import socket
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from typing import Literal

from app.ports import SolveProgress, StoreUnavailable, Waiting, WorkerBeat
from app.runs import Progress
from app.usecases.fleet_solve import FleetSolver

__all__ = ["BEAT_KEEP_S", "WorkerStatus", "Heartbeat", "new_worker_id"]

log = logging.getLogger(__name__)

BEAT_KEEP_S = 86400.0
"""How long the store keeps a city's beats after the last one: the status says when a gone worker was last
seen for a day."""


def new_worker_id() -> str:
    """``host:pid:random``: tells apart two workers on one host and a restarted one."""
    return f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(3)}"


class WorkerStatus:
    """What the worker is doing now, as its heartbeat tells it (thread-safe: the loop, the runner's
    progress callback and the heartbeat thread share it)."""

    def __init__(
        self, *, embedded: bool, poll_s: float, clock: Callable[[], float] = time.time, worker_id: str = ""
    ) -> None:
        self.worker_id = worker_id or new_worker_id()
        self.embedded = embedded
        self.poll_s = poll_s
        self.clock = clock
        self.started_at_s = clock()
        self._lock = threading.Lock()
        self._solving: tuple[str, SolveProgress] | None = None  # (city, its solve)
        self._next: dict[str, tuple[int, float]] = {}  # city -> (interval, due at)
        self._waiting: dict[str, Waiting] = {}  # city -> why it cannot be sized now
        self.changed = threading.Event()  # set when a solve starts, ends or finishes a run: beat now

    @contextmanager
    def solving(
        self, city: str, interval: int, trigger: Literal["schedule", "request"], request_id: str | None
    ) -> Iterator[None]:
        """Mark the city's solve of ``interval`` as in progress for the block."""
        with self._lock:
            self._solving = (city, SolveProgress(int(interval), trigger, request_id, self.clock()))
        self.changed.set()
        try:
            yield
        finally:
            with self._lock:
                self._solving = None
            self.changed.set()

    def progress(self, p: Progress) -> None:
        """The runs of the solve in progress (the runner's progress callback); beats at once when the count
        of runs, finished or failed, moves (a run starting waits for the next beat)."""
        with self._lock:
            if self._solving is None:
                return
            city, s = self._solving
            moved = (s.runs_total, s.runs_done, s.runs_failed) != (p.total, p.done, p.failed)
            self._solving = (
                city,
                replace(
                    s,
                    runs_total=p.total,
                    runs_done=p.done,
                    runs_cached=p.cached,
                    runs_running=p.running,
                    runs_failed=p.failed,
                ),
            )
        if moved:
            self.changed.set()

    def schedule(self, city: str, interval: int, due_at_s: float) -> None:
        """The city's next scheduled solve: hour ``interval``, due at ``due_at_s``."""
        with self._lock:
            self._next[city] = (int(interval), float(due_at_s))

    def waiting(self, city: str, kind: str, reason: str) -> bool:
        """The city cannot be sized now, for ``reason``; whether that is news (another kind or reason than
        the one already shown)."""
        with self._lock:
            old = self._waiting.get(city)
            if old is not None and (old.kind, old.reason) == (kind, reason):
                return False
            self._waiting[city] = Waiting(kind, reason, self.clock())
        self.changed.set()
        return True

    def sizable(self, city: str) -> None:
        """The city can be sized again (a solve ran)."""
        with self._lock:
            gone = self._waiting.pop(city, None)
        if gone is not None:
            self.changed.set()

    def beat(self, city: str) -> WorkerBeat:
        """The heartbeat of the city now."""
        with self._lock:
            solving = self._solving[1] if self._solving and self._solving[0] == city else None
            nxt = self._next.get(city)
            waiting = self._waiting.get(city)
        return WorkerBeat(
            worker_id=self.worker_id,
            seen_at_s=self.clock(),
            started_at_s=self.started_at_s,
            host=socket.gethostname(),
            pid=os.getpid(),
            embedded=self.embedded,
            poll_s=self.poll_s,
            solving=solving,
            next_interval=None if nxt is None else nxt[0],
            next_due_at_s=None if nxt is None else nxt[1],
            waiting=waiting,
        )


class Heartbeat:
    """Writes the worker's beat for each of ``cities`` every ``interval_s`` (and when a solve starts, ends or
    finishes a run) on a daemon thread; a store outage is logged once and retried at the next beat."""

    def __init__(
        self,
        service: FleetSolver,
        status: WorkerStatus,
        cities: Sequence[str],
        *,
        interval_s: float,
        keep_s: float = BEAT_KEEP_S,
    ) -> None:
        self.service = service
        self.status = status
        self.cities = list(cities)
        self.interval_s = interval_s
        self.keep_s = keep_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._failing = False

    def beat_once(self) -> bool:
        """One beat for every city; whether the store took them all."""
        try:
            for city in self.cities:
                self.service.beat(city, self.status.beat(city), self.keep_s)
        except StoreUnavailable as exc:
            if not self._failing:
                log.warning("fleet worker heartbeat: store unavailable, retrying: %s", exc)
            self._failing = True
            return False
        if self._failing:
            log.info("fleet worker heartbeat: store reachable again")
        self._failing = False
        return True

    def _run(self) -> None:
        while not self._stop.is_set():
            self.status.changed.clear()
            self.beat_once()
            self.status.changed.wait(self.interval_s)

    def start(self) -> None:
        """Beat now and then every ``interval_s`` until ``stop``."""
        self._thread = threading.Thread(target=self._run, name="fleet-heartbeat", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop beating (the last beat stays until it is stale)."""
        self._stop.set()
        self.status.changed.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
