"""The worker loop: every few seconds, claim queued solve requests and run the solves that are due.

Thin by design: *when* lives here (``app.worker.schedule``), *what* in the use case
``app.usecases.fleet_solve.FleetSolver.solve``. A solve of hour ``h`` is due from ``lead_s`` before ``h``
starts (default: the start of the previous hour, city local time); each worker tries it once, and the store
lock plus the "already solved" check make sure only one of several workers solves it. A request from
``POST /v1/cities/{city}/fleet/solve`` is solved for the coming hour at the next poll, even if that hour is
already solved. A city that cannot be sized yet (too little history, no tasks) starts no run: its heartbeat
says why, and the reason is logged once, not at every hour.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from typing import Literal

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

from app.ports import StoreUnavailable
from app.runs import Progress, Runner
from app.usecases.fleet_solve import FleetSolver, SolveOutcome
from app.worker.heartbeat import Heartbeat, WorkerStatus
from app.worker.schedule import coming_interval, due_interval
from services.city import Horizon
from services.model import IntervalKey

__all__ = ["WorkerMetrics", "FleetWorker", "AssembledWorker"]

log = logging.getLogger(__name__)

_RUN_STATES = ("queued", "running", "done", "cached", "failed", "retried")


class WorkerMetrics:
    """The worker's Prometheus metrics (its own registry; served when ``SD_WORKER_METRICS_PORT`` is set)."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        self.solves = Counter(
            "sd_fleet_solves",
            "Fleet-sizing solve attempts by outcome (published, failed, waiting, skipped, busy).",
            ["outcome"],
            registry=self.registry,
        )
        self.solve_seconds = Histogram(
            "sd_fleet_solve_seconds",
            "Wall time of published and failed solves.",
            buckets=(1, 5, 15, 30, 60, 120, 300, 600, 1800),
            registry=self.registry,
        )
        for outcome in ("published", "failed", "waiting", "skipped", "busy"):
            self.solves.labels(outcome=outcome)
        self.runs = Gauge(
            "sd_fleet_runs",
            "Simulation runs of the current (else the last) solve by state: queued, running, done (cached "
            "included), cached, failed, and retried (restarts after a lost engine worker).",
            ["state"],
            registry=self.registry,
        )
        for state in _RUN_STATES:
            self.runs.labels(state=state)

    def progress(self, p: Progress) -> None:
        """Show where the current solve's runs stand (the runner calls this as runs start and finish)."""
        values = (p.queued, p.running, p.done, p.cached, p.failed, p.retried)
        for state, value in zip(_RUN_STATES, values, strict=True):
            self.runs.labels(state=state).set(value)

    def observe(self, outcome: SolveOutcome) -> None:
        """Count one attempt."""
        self.solves.labels(outcome=outcome.status).inc()
        if outcome.status in ("published", "failed"):
            self.solve_seconds.observe(outcome.wall_s)


class FleetWorker:
    """Polls the solve queues and runs the scheduled solves of ``cities``."""

    def __init__(
        self,
        sizing: FleetSolver,
        cities: Sequence[str],
        *,
        lead_s: float = 3600.0,
        poll_s: float = 5.0,
        clock: Callable[[], float] = time.time,
        metrics: WorkerMetrics | None = None,
        status: WorkerStatus | None = None,
    ) -> None:
        """``status`` (the heartbeat's) learns of every solve and each city's next scheduled one."""
        self.sizing = sizing
        self.cities = list(cities)
        self.lead_s = lead_s
        self.poll_s = poll_s
        self.clock = clock
        self.metrics = metrics or WorkerMetrics()
        self.status = status
        self._attempted: dict[str, int] = {}  # city -> the last hour this worker tried on schedule
        self._horizons: dict[str, Horizon] = {}

    def horizon(self, city: str) -> Horizon:
        """The city's operating horizon (the city is loaded once)."""
        if city not in self._horizons:
            self._horizons[city] = self.sizing.load_city(city).horizon
        return self._horizons[city]

    def _done(self, outcome: SolveOutcome) -> SolveOutcome:
        self.metrics.observe(outcome)
        if outcome.status == "waiting":
            kind, reason = outcome.waiting_for or "", outcome.reason or ""
            news = self.status.waiting(outcome.city, kind, reason) if self.status else True
            if news:
                log.warning("fleet %s: not sized, no run started: %s", outcome.city, outcome.reason)
        elif outcome.status in ("published", "failed") and self.status is not None:
            self.status.sizable(outcome.city)
        if outcome.status == "skipped":
            log.info("fleet %s, interval %d: already solved", outcome.city, outcome.interval)
        elif outcome.status == "busy":
            log.info("fleet %s, interval %d: another worker is solving it", outcome.city, outcome.interval)
        return outcome

    @contextmanager
    def _solving(
        self, city: str, target: int, trigger: Literal["schedule", "request"], request_id: str | None = None
    ) -> Iterator[None]:
        """The heartbeat shows the solve for the block."""
        with self.status.solving(city, target, trigger, request_id) if self.status else nullcontext():
            yield

    def next_scheduled(self, city: str) -> tuple[IntervalKey, float]:
        """The hour this worker will solve next on schedule and when that solve is due (the coming hour,
        or the one after it when this worker already tried the coming one)."""
        hz = self.horizon(city)
        k = coming_interval(hz, self.clock())
        if self._attempted.get(city) == k:
            k = coming_interval(hz, hz.interval_start_s(k))
        return k, hz.interval_start_s(k) - self.lead_s

    def requested(self, city: str) -> SolveOutcome | None:
        """Claim the city's pending request, if any, and solve the coming hour for it. When another worker
        holds that hour's lock the request goes back on the queue for the next poll."""
        request = self.sizing.claim_request(city)
        if request is None:
            return None
        target = coming_interval(self.horizon(city), self.clock())
        with self._solving(city, target, "request", request.request_id):
            outcome = self.sizing.solve(city, target, request=request)
        if outcome.status == "busy":
            self.sizing.requeue(city, request)
        return self._done(outcome)

    def scheduled(self, city: str) -> SolveOutcome | None:
        """Solve the coming hour if it is due and this worker has not tried it yet."""
        target = due_interval(self.horizon(city), self.clock(), self.lead_s)
        if target is None or self._attempted.get(city) == target:
            return None
        with self._solving(city, target, "schedule"):
            outcome = self.sizing.solve(city, target)
        if outcome.status != "busy":  # busy: try again at the next poll (the holder may fail)
            self._attempted[city] = target
        return self._done(outcome)

    def tick(self) -> list[SolveOutcome]:
        """One pass over the cities: requests first, then scheduled solves. A store outage is logged and
        the pass goes on with the next city (the loop survives it)."""
        outcomes: list[SolveOutcome] = []
        for city in self.cities:
            for step in (self.requested, self.scheduled):
                try:
                    outcome = step(city)
                except StoreUnavailable as exc:
                    log.warning("fleet %s: store unavailable, retrying at the next poll: %s", city, exc)
                    break
                if outcome is not None:
                    outcomes.append(outcome)
            if self.status is not None:
                self.status.schedule(city, *self.next_scheduled(city))
        return outcomes

    def once(self, city: str) -> SolveOutcome:
        """Solve the coming hour now (even if already solved), unless another worker is solving it."""
        target = coming_interval(self.horizon(city), self.clock())
        with self._solving(city, target, "schedule"):
            return self._done(self.sizing.solve(city, target, force=True))

    def run(self, stop: threading.Event) -> None:
        """Tick every ``poll_s`` seconds until ``stop`` is set (a pass that raises is logged, and the loop
        goes on at the next poll: a worker that dies silently would leave requests to nobody)."""
        cities = ", ".join(self.cities)
        log.info(
            "fleet worker: %s; polling every %.0f s, solving %.0f s ahead", cities, self.poll_s, self.lead_s
        )
        while not stop.is_set():
            try:
                self.tick()
            except Exception:
                log.exception("fleet worker: a pass failed; next pass in %.0f s", self.poll_s)
            stop.wait(self.poll_s)


@dataclass(frozen=True, slots=True)
class AssembledWorker:
    """A worker's parts (``app.bootstrap.build_worker``): the loop, its heartbeat (not started), the runner
    to close, its metrics."""

    worker: FleetWorker
    heartbeat: Heartbeat
    runner: Runner
    metrics: WorkerMetrics

    def serve(self, stop: threading.Event) -> None:
        """Beat and run the loop until ``stop`` is set; then stop beating (the runner stays open)."""
        self.heartbeat.start()
        try:
            self.worker.run(stop)
        finally:
            self.heartbeat.stop()
