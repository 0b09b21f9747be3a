"""Use cases: the only door to the store, one object per concern. They take the core's types (a resolved
epoch, tasks, an interval key) and return the core's results; the API turns requests into those types
(``app.api.inputs``) and renders the results (``app.schemas``), and the fleet worker reads and writes
through ``FleetSolver``.

- ``epochs``: ``EpochService``, posted epochs solved and committed exactly once, committed epochs read back;
- ``tasks``: ``TaskService``, the POIs the platform registers for monitoring;
- ``admin``: ``AdminService``, rewinding or resetting a city's epoch stream;
- ``coverage``: ``CoverageService``, Lambda, the coverage rate and Gamma of an interval;
- ``readiness``: ``ReadinessService``, whether the instance can take epochs;
- ``fleet``: ``FleetService``, the API's side of fleet sizing (recommendations, solve requests, status);
- ``fleet_history``: the platform's recorded history (requests and fleet by local day) and the sizing
  configuration of a city, which the API's status and the fleet solve share;
- ``fleet_solve``: ``FleetSolver``, the fleet worker's side: solve requests, the solve (history window,
  task set, runs, plan, sweep) and publishing, its heartbeat's record (imported by the worker only: it
  brings the simulation runs);
- ``cities``: ``CityCatalog``, the served cities by name.

``UseCases`` holds one of each of the API's, built over one store by ``UseCases.over``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass

from app.ports import Store
from app.usecases.admin import AdminService, StreamChange
from app.usecases.cities import CityCatalog
from app.usecases.coverage import Coverage, CoverageService
from app.usecases.epoch_record import (
    EpochCommand,
    EpochReader,
    EpochRenderer,
    EpochResult,
    StoredDecision,
    read_epoch,
    render_epoch,
)
from app.usecases.epochs import (
    LOOKAHEAD_INTERVALS,
    DecideFn,
    EpochLimits,
    EpochLog,
    EpochOutcome,
    EpochRoutes,
    EpochService,
)
from app.usecases.fleet import START_WORKER_HINT, FleetService, FleetStatus
from app.usecases.fleet_history import SizingConfig
from app.usecases.readiness import ReadinessService
from app.usecases.tasks import TaskService

__all__ = [
    "AdminService",
    "CityCatalog",
    "Coverage",
    "CoverageService",
    "DecideFn",
    "EpochCommand",
    "EpochLimits",
    "EpochLog",
    "EpochOutcome",
    "EpochReader",
    "EpochRenderer",
    "EpochResult",
    "EpochRoutes",
    "EpochService",
    "FleetService",
    "FleetStatus",
    "LOOKAHEAD_INTERVALS",
    "ReadinessService",
    "START_WORKER_HINT",
    "SizingConfig",
    "StoredDecision",
    "StreamChange",
    "TaskService",
    "UseCases",
]


_DEFAULT_LIMITS = EpochLimits()
_DEFAULT_SIZING = SizingConfig()


@dataclass(frozen=True, slots=True)
class UseCases:
    """The API's use cases over one store (``create_app`` builds them; the routers take the one they use)."""

    cities: CityCatalog
    epochs: EpochService
    tasks: TaskService
    admin: AdminService
    coverage: CoverageService
    readiness: ReadinessService
    fleet: FleetService

    @classmethod
    def over(
        cls,
        cities: CityCatalog,
        store: Store,
        decide: DecideFn,
        *,
        render_epoch: EpochRenderer = render_epoch,
        read_epoch: EpochReader = read_epoch,
        limits: EpochLimits = _DEFAULT_LIMITS,
        worker_stale_s: float = 30.0,
        sizing: SizingConfig = _DEFAULT_SIZING,
        clock: Callable[[], float] = time.time,
        foreground: Callable[[], AbstractContextManager[None]] = nullcontext,
    ) -> UseCases:
        """Every use case of the API over ``store``; ``clock`` (POSIX seconds) is the epoch time window's
        and the worker heartbeats' (``worker_stale_s``: a worker not seen for longer is gone); ``sizing`` is
        the fleet worker's settings (M and the look-back of the fleet status); ``foreground`` is held
        by every epoch's request (the embedded fleet worker pauses its runs meanwhile)."""
        return cls(
            cities=cities,
            epochs=EpochService(
                cities,
                store,
                decide,
                render_epoch=render_epoch,
                read_epoch=read_epoch,
                limits=limits,
                clock=clock,
                foreground=foreground,
            ),
            tasks=TaskService(cities, store),
            admin=AdminService(cities, store),
            coverage=CoverageService(cities, store),
            readiness=ReadinessService(cities, store),
            fleet=FleetService(cities, store, stale_s=worker_stale_s, sizing=sizing, clock=clock),
        )
