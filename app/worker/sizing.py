"""The fleet-sizing use case: solve the coming hour of a city and publish the recommendation (docs/FLEET.md).

One solve: pick the demand history (the last M local days the service recorded demand on, or a seeded
synthetic history when it has fewer), simulate every (size, day) as a whole day (cached), form the KPI
samples, call :func:`services.fleet.plan_fleet`, and publish the document with the next version. Every
failure -- a run that raised, bad samples, a lost version race -- keeps the current recommendation and is
recorded in the history with its reason.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from app.experiment.workload import RunSpec, load
from app.ports import FleetRecord, SolveRequest, Store
from app.schemas import format_time
from app.schemas_fleet import (
    ChoiceOut,
    ChosenOut,
    CompletionTargetOut,
    DataWindowOut,
    HourChoiceOut,
    RecommendationBody,
    SimulationOut,
    SolveStatsOut,
    rows_out,
)
from app.settings import Settings
from app.worker.recorded import recorded_days
from app.worker.runs import DayJob, DayResult, DayRunner
from app.worker.schedule import interval_start_s
from services.city import City
from services.fleet import Ambiguity, Choice, FleetPlan, plan_fleet
from services.model import IntervalKey
from services.sim.demand import DemandSet

__all__ = [
    "KPI_NAME",
    "SizingConfig",
    "HistoryDay",
    "HistoryWindow",
    "SolveOutcome",
    "SolveFailed",
    "FleetSizing",
    "lock_name",
    "recommendation_body",
]

log = logging.getLogger(__name__)

KPI_NAME = "design KPI: monitoring cost per instrumented vehicle-hour, CNY (METHOD section 7)"
_MAX_REASON = 2000


@dataclass(frozen=True, slots=True)
class SizingConfig:
    """What a solve simulates and how it decides (from the ``SD_WORKER_*`` settings)."""

    sizes: tuple[int, ...] = (10, 20, 30, 40, 50, 60)
    days: int = 10
    ambiguity: Ambiguity = Ambiguity()
    completion_target: float | None = 0.95
    n0: int = 60
    n_tasks: int = 85
    rate_per_hour: float | None = None
    seed: int = 0
    lookback_days: int = 9
    history_limit: int = 100
    lock_ttl_s: float = 1800.0

    def __post_init__(self) -> None:
        if not self.sizes or any(x < 1 for x in self.sizes) or len(set(self.sizes)) != len(self.sizes):
            raise ValueError(f"sizes must be distinct positive integers, got {self.sizes}")
        if self.days < 2:
            raise ValueError(f"days must be at least 2 (M samples per size), got {self.days}")

    @classmethod
    def from_settings(cls, s: Settings) -> SizingConfig:
        """The configuration the settings describe; recorded demand is looked for as far back as kept."""
        return cls(
            sizes=tuple(sorted(s.worker_sizes)),
            days=s.worker_days,
            ambiguity=Ambiguity(s.worker_divergence, s.worker_alpha, s.worker_support, s.worker_bins),
            completion_target=s.worker_completion_target,
            n0=s.worker_n0,
            n_tasks=s.worker_tasks,
            rate_per_hour=s.worker_rate_per_hour,
            seed=s.worker_seed,
            lookback_days=max(1, s.retention_s // 86400 + 1),
            history_limit=s.worker_history,
            lock_ttl_s=float(s.worker_lock_ttl_s),
        )


@dataclass(frozen=True, slots=True)
class HistoryDay:
    """One demand sample: its label, the ``RunSpec`` day (seeds tasks; the generator's day when synthetic)
    and the recorded demand (``None``: synthetic)."""

    label: str
    spec_day: int
    demand: DemandSet | None


@dataclass(frozen=True, slots=True)
class HistoryWindow:
    """The M demand days of a solve and where they came from."""

    source: Literal["recorded", "synthetic"]
    days: tuple[HistoryDay, ...]
    recorded_available: int
    note: str


@dataclass(frozen=True, slots=True)
class SolveOutcome:
    """What one solve attempt did: ``published`` (``version``), ``failed`` (``reason``, recorded in the
    history), ``skipped`` (the hour was already solved) or ``busy`` (another worker holds its lock)."""

    city: str
    interval: int
    status: Literal["published", "failed", "skipped", "busy"]
    version: int | None = None
    reason: str | None = None
    request_id: str | None = None
    wall_s: float = 0.0


class SolveFailed(RuntimeError):
    """A solve could not produce a recommendation (the message is the reason recorded in the history)."""


def lock_name(interval: int) -> str:
    """The store lock of one hour's solve."""
    return f"fleet-solve:{int(interval)}"


def recommendation_body(
    city: City,
    target: IntervalKey,
    plan: FleetPlan,
    config: SizingConfig,
    window: HistoryWindow,
    requests_per_day: list[int],
    stats: SolveStatsOut,
    *,
    trigger: Literal["schedule", "request"],
    request_id: str | None,
) -> RecommendationBody:
    """The published document of a plan for hour ``target`` (the API adds version and computed_at)."""
    cfg, hz = config, city.horizon
    position = hz.position(target)
    first = target - position

    def hour(h: int, choice: Choice) -> HourChoiceOut:
        base = ChoiceOut.of(choice).model_dump()
        return HourChoiceOut(**base, interval=hz.label(first + h), position=h)

    by_hour = [hour(h, c) for h, c in enumerate(plan.rolling.choices)]
    goal = plan.completion
    return RecommendationBody(
        city=city.name,
        interval=hz.label(target),
        interval_start=format_time(interval_start_s(hz, target), hz.timezone),
        position=position,
        trigger=trigger,
        request_id=request_id,
        kpi=KPI_NAME,
        chosen=ChosenOut(
            deterministic=plan.deterministic.size,
            dro=plan.dro.size,
            dro_rh=plan.rolling.choices[position].size,
            completion_target=None if goal is None else goal.size,
        ),
        deterministic=ChoiceOut.of(plan.deterministic),
        dro=ChoiceOut.of(plan.dro),
        dro_rh=by_hour[position],
        dro_rh_by_hour=by_hour,
        hour_table=rows_out(plan.rolling.tables[position]),
        daily_table=rows_out(plan.daily),
        completion_target=None if goal is None else CompletionTargetOut.of(goal),
        divergence=cfg.ambiguity.divergence,
        alpha=cfg.ambiguity.alpha,
        support=cfg.ambiguity.support,
        bins=cfg.ambiguity.bins,
        sizes=list(cfg.sizes),
        data_window=DataWindowOut(
            source=window.source,
            days=[d.label for d in window.days],
            n_days=len(window.days),
            requests_per_day=requests_per_day,
            recorded_days_available=window.recorded_available,
            seed=cfg.seed if window.source == "synthetic" else None,
            note=window.note,
        ),
        simulation=SimulationOut(
            n0=cfg.n0, n_tasks=cfg.n_tasks, rate_per_hour=cfg.rate_per_hour, seed=cfg.seed
        ),
        solve=stats,
    )


def _load_city(name: str) -> City:
    return load(name)[0]


class FleetSizing:
    """Solves and publishes; the worker loop (``app.worker.service``) decides when."""

    def __init__(
        self,
        store: Store,
        runner: DayRunner,
        config: SizingConfig,
        *,
        clock: Callable[[], float] = time.time,
        load_city: Callable[[str], City] = _load_city,
    ) -> None:
        self.store = store
        self.runner = runner
        self.config = config
        self.clock = clock
        self.load_city = load_city

    # ------------------------------------------------------------------ inputs

    def window(self, city: City, target: IntervalKey) -> HistoryWindow:
        """The last M recorded local days before the target hour's date, else the seeded synthetic days."""
        cfg = self.config
        day = city.horizon.local_start(target).date()
        found = recorded_days(self.store, city, day, cfg.days, cfg.lookback_days)
        if len(found) >= cfg.days:
            return HistoryWindow(
                "recorded",
                tuple(HistoryDay(d.date.isoformat(), d.date.toordinal(), d.demand) for d in found),
                len(found),
                f"the {cfg.days} most recent local days with recorded requests before {day}",
            )
        return HistoryWindow(
            "synthetic",
            tuple(HistoryDay(f"synthetic-{d}", d, None) for d in range(1, cfg.days + 1)),
            len(found),
            f"{len(found)} day(s) of recorded demand in the {cfg.lookback_days} days before {day}, "
            f"fewer than M = {cfg.days}: seeded synthetic history, days 1..{cfg.days} of the city's "
            f"generator (seed {cfg.seed})",
        )

    def jobs(self, city: City, window: HistoryWindow) -> dict[tuple[int, int], DayJob]:
        """One whole-day job per (size, day index)."""
        cfg = self.config
        out: dict[tuple[int, int], DayJob] = {}
        for x in cfg.sizes:
            for i, day in enumerate(window.days):
                spec = RunSpec(
                    city=city.name,
                    n1=x,
                    n0=cfg.n0,
                    seed=cfg.seed,
                    day=day.spec_day,
                    n_tasks=cfg.n_tasks,
                    rate_per_hour=cfg.rate_per_hour if day.demand is None else None,
                )
                out[(x, i)] = DayJob(spec, day.demand)
        return out

    # ------------------------------------------------------------------ the solve

    def compute(
        self,
        city: City,
        target: IntervalKey,
        *,
        trigger: Literal["schedule", "request"],
        request_id: str | None,
    ) -> RecommendationBody:
        """Simulate, decide and build the document; ``SolveFailed`` with the reason when it cannot."""
        cfg = self.config
        window = self.window(city, target)
        jobs = self.jobs(city, window)
        batch = self.runner.run(list(jobs.values()))
        if batch.failures:
            shown = "; ".join(f"{k}: {v}" for k, v in sorted(batch.failures.items())[:3])
            raise SolveFailed(f"{len(batch.failures)} of {len(jobs)} runs failed (partial solve): {shown}")
        res: dict[tuple[int, int], DayResult] = {key: batch.results[job.key] for key, job in jobs.items()}
        n_days, hz = len(window.days), city.horizon
        daily = {x: [res[(x, i)].design_kpi for i in range(n_days)] for x in cfg.sizes}
        hourly = [
            {x: [res[(x, i)].hour_design_kpi[h] for i in range(n_days)] for x in cfg.sizes}
            for h in range(hz.n_intervals)
        ]
        target_on = cfg.completion_target is not None and cfg.n_tasks > 0
        completion = {x: [res[(x, i)].completion_rate for i in range(n_days)] for x in cfg.sizes}
        try:
            plan = plan_fleet(
                daily,
                hourly,
                cfg.ambiguity,
                completion=completion if target_on else None,
                target=cfg.completion_target if target_on else None,
            )
        except ValueError as exc:
            raise SolveFailed(f"fleet sizing rejected the samples: {exc}") from exc
        sizes_requests = [res[(cfg.sizes[0], i)].n_requests for i in range(n_days)]
        stats = SolveStatsOut(
            runs=len(batch.results), cached_runs=batch.cached, wall_s=batch.wall_s, jobs=self.runner.jobs
        )
        return recommendation_body(
            city, target, plan, cfg, window, sizes_requests, stats, trigger=trigger, request_id=request_id
        )

    def solve(
        self, city_name: str, target: IntervalKey, *, request: SolveRequest | None = None, force: bool = False
    ) -> SolveOutcome:
        """Solve hour ``target`` under its store lock and publish; ``force`` (and every admin request) solves
        even when the current recommendation already covers that hour."""
        started = time.perf_counter()
        request_id = None if request is None else request.request_id
        token = self.store.acquire_lock(city_name, lock_name(target), self.config.lock_ttl_s)
        if token is None:
            return SolveOutcome(city_name, target, "busy", request_id=request_id)
        try:
            current = self.store.current_recommendation(city_name)
            if current is not None and current.interval == target and not (force or request is not None):
                return SolveOutcome(city_name, target, "skipped", version=current.version)
            expected = 0 if current is None or current.version is None else current.version
            trigger: Literal["schedule", "request"] = "schedule" if request is None else "request"
            try:
                city = self.load_city(city_name)
                body = self.compute(city, target, trigger=trigger, request_id=request_id)
            except Exception as exc:  # noqa: BLE001 - any failure keeps the last good recommendation
                if not isinstance(exc, SolveFailed):
                    log.exception("fleet solve of %s for interval %d raised", city_name, target)
                reason = str(exc) if isinstance(exc, SolveFailed) else f"{type(exc).__name__}: {exc}"
                return self._fail(city_name, target, reason, request_id, started)
            record = FleetRecord(
                "published",
                self.clock(),
                int(target),
                version=expected + 1,
                body_json=body.model_dump_json(),
                request_id=request_id,
            )
            result = self.store.publish_recommendation(city_name, record, self.config.history_limit)
            if result.status != "published":
                reason = f"superseded: version {result.version} was published while this solve ran"
                return self._fail(city_name, target, reason, request_id, started)
            wall = time.perf_counter() - started
            log.info(
                "fleet %s, hour %s: published version %d (deterministic %d, DRO %d, DRO_RH %d) in %.1f s",
                city_name,
                body.interval,
                result.version,
                body.chosen.deterministic,
                body.chosen.dro,
                body.chosen.dro_rh,
                wall,
            )
            return SolveOutcome(city_name, target, "published", result.version, None, request_id, wall)
        finally:
            self.store.release_lock(city_name, lock_name(target), token)

    def _fail(
        self, city: str, target: IntervalKey, reason: str, request_id: str | None, started: float
    ) -> SolveOutcome:
        """Record a failed solve in the history (the current recommendation stays) and log it."""
        reason = reason[:_MAX_REASON]
        log.error(
            "fleet %s, interval %d: solve failed, last good recommendation kept: %s", city, target, reason
        )
        record = FleetRecord("failed", self.clock(), int(target), reason=reason, request_id=request_id)
        self.store.record_solve_failure(city, record, self.config.history_limit)
        return SolveOutcome(city, target, "failed", None, reason, request_id, time.perf_counter() - started)
