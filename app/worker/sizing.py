"""The fleet worker's solve: the coming hour of a city, solved and published (docs/FLEET.md).

One solve: pick the demand history (the last M local days the service recorded demand on, or a seeded
synthetic history when it has fewer), simulate every (size, day) as a whole day (cached), form the KPI
samples of the platform's total cost per hour (DRO_RH conditioned on the hours the day has shown), call
:func:`services.fleet.sizing.plan_fleet`, and publish the recommendation with the next version (the
document is rendered by the injected ``render``, ``app.schemas.fleet.render_recommendation`` in the worker).
What it reads and writes goes through ``app.usecases.SizingService``, under the hour's lock. Every
failure -- a run that raised, bad samples, a lost version race -- keeps the current recommendation and is
recorded in the history with its reason.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from app.cities import CityRegistry
from app.ports import FleetRecord, SolveRequest
from app.runs import ExecutorUnavailable, ProgressFn, RunJob, Runner, RunResult, RunSpec, TaskTemplate
from app.runs.outcomes import day_outcomes, hourly_volumes
from app.settings import Settings
from app.usecases.sizing import SizingService
from app.worker.recorded import DemandLog, demand_from_records, recorded_days
from services.city import City
from services.fleet.sizing import Ambiguity, CostModel, FleetPlan, SubsidyPoint, plan_fleet, subsidy_sweep
from services.model import IntervalKey
from services.sim.demand import DemandSet

__all__ = [
    "OBJECTIVE",
    "TaskSet",
    "Observed",
    "observed_today",
    "SizingConfig",
    "HistoryDay",
    "HistoryWindow",
    "SolveStats",
    "Recommendation",
    "RecommendationRenderer",
    "SolveOutcome",
    "SolveFailed",
    "FleetSizing",
]

log = logging.getLogger(__name__)

OBJECTIVE = (
    "total platform cost per hour, CNY: 1.5 CNY/km x Step 3 km per hour + subsidy x N1 "
    "(docs/METHOD.md section 7); the per-vehicle design KPI is reported, not minimized"
)
_MAX_REASON = 2000


@dataclass(frozen=True, slots=True)
class SizingConfig:
    """What a solve simulates and how it decides (from the ``SD_WORKER_*`` settings)."""

    sizes: tuple[int, ...] = (10, 20, 30, 40, 50, 60)
    days: int = 10
    ambiguity: Ambiguity = Ambiguity()
    completion_target: float | None = None
    subsidy_cny_per_vehicle_hour: float = 0.0
    subsidy_sweep: tuple[float, ...] = ()
    rolling_days: int = 7
    reach_s: float = 1200.0
    vary_tasks: bool = False
    n0: int = 60
    n_tasks: int = 85
    rate_per_hour: float | None = None
    seed: int = 0
    lookback_days: int = 9

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
            subsidy_cny_per_vehicle_hour=s.worker_subsidy_cny_per_vehicle_hour,
            subsidy_sweep=tuple(s.worker_subsidy_sweep),
            rolling_days=s.worker_rolling_days,
            reach_s=s.worker_reach_s,
            vary_tasks=s.worker_vary_tasks,
            n0=s.worker_n0,
            n_tasks=s.worker_tasks,
            rate_per_hour=s.worker_rate_per_hour,
            seed=s.worker_seed,
            lookback_days=max(1, s.retention_s // 86400 + 1),
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


@dataclass(frozen=True, slots=True)
class TaskSet:
    """The POI tasks every simulated day of a solve carries: the platform's registered tasks of the day
    solved for (as templates), or the seeded synthetic draw (one set, or one per day with ``vary_tasks``)."""

    source: Literal["registered", "synthetic", "synthetic_per_day"]
    templates: tuple[TaskTemplate, ...] | None


@dataclass(frozen=True, slots=True)
class Observed:
    """The day solved for so far: its date and the recorded requests of its whole hours already past."""

    date: str
    requests_per_hour: tuple[int, ...]


def observed_today(source: DemandLog, city: City, target: IntervalKey, now_s: float) -> Observed:
    """Recorded requests per hour of the target's local day, for the horizon hours that ended by ``now_s``
    (never the target hour or later)."""
    hz = city.horizon
    day = hz.local_start(target).date()
    position = hz.position(target)
    start = hz.start_s(day)
    past = min(position, max(0, int((now_s - start) // hz.interval_s)))
    if past == 0:
        return Observed(day.isoformat(), ())
    records = source.recorded_day(city, day)
    if not records:  # the service saw no epoch today: nothing observed (not a day of zero demand)
        return Observed(day.isoformat(), ())
    counts = [0] * past
    if records:
        for r in demand_from_records(city, day, records).requests:
            i = int((r.time_s - start) // hz.interval_s)
            if 0 <= i < past:
                counts[i] += 1
    return Observed(day.isoformat(), tuple(counts))


@dataclass(frozen=True, slots=True)
class SolveStats:
    """What a solve cost: runs simulated (``cached_runs`` of them cached), wall time, parallel jobs."""

    runs: int
    cached_runs: int
    wall_s: float
    jobs: int


@dataclass(frozen=True, slots=True)
class Recommendation:
    """A solve's result for hour ``target`` of ``city``: the plan and what it was computed from.

    ``objective`` names what the methods minimize; ``requests_per_day`` counts the requests of each history
    day; ``observed`` is what the target's day showed before the solve; ``tasks`` the tasks every day carried;
    ``sweep`` every method's choice at the configured subsidy and the sweep's others (the trade-off curve).
    """

    city: City
    target: IntervalKey
    plan: FleetPlan
    config: SizingConfig
    window: HistoryWindow
    requests_per_day: tuple[int, ...]
    stats: SolveStats
    trigger: Literal["schedule", "request"]
    request_id: str | None
    observed: Observed
    tasks: TaskSet
    objective: str = OBJECTIVE
    sweep: tuple[SubsidyPoint, ...] = ()

    @property
    def position(self) -> int:
        """Hour of the horizon solved for, 0-based."""
        return self.city.horizon.position(self.target)


RecommendationRenderer = Callable[[Recommendation], str]
"""The published document of a recommendation (the API serves it with its version and publication time)."""


class FleetSizing:
    """Solves and publishes; the worker loop (``app.worker.service``) decides when."""

    def __init__(
        self,
        service: SizingService,
        runner: Runner,
        config: SizingConfig,
        *,
        render: RecommendationRenderer,
        cities: CityRegistry | None = None,
        clock: Callable[[], float] = time.time,
        progress: ProgressFn | None = None,
    ) -> None:
        """``cities`` defaults to the bundled cities (``CityRegistry.from_settings`` in a deployment);
        ``progress`` sees the runs of every solve start and finish (the worker's metrics)."""
        self.service = service
        self.runner = runner
        self.config = config
        self.render = render
        self.cities = cities if cities is not None else CityRegistry()
        self.clock = clock
        self.progress = progress

    def load_city(self, name: str) -> City:
        """The city (``UnknownCity`` when the registry does not serve it)."""
        return self.cities.get(name)

    def claim_request(self, city: str) -> SolveRequest | None:
        """Take the city's pending admin request off the queue, if any."""
        return self.service.claim_request(city)

    def requeue(self, city: str, request: SolveRequest) -> None:
        """Put a claimed request back for the next poll (another worker holds the hour's lock)."""
        self.service.requeue(city, request)

    # ------------------------------------------------------------------ inputs

    def window(self, city: City, target: IntervalKey) -> HistoryWindow:
        """The last M recorded local days before the target hour's date, else the seeded synthetic days."""
        cfg = self.config
        day = city.horizon.local_start(target).date()
        found = recorded_days(self.service, city, day, cfg.days, cfg.lookback_days)
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

    def task_set(self, city: City, target: IntervalKey) -> TaskSet:
        """The platform's registered tasks scheduled within the horizon of the target's day, as templates;
        without any, the seeded synthetic draw."""
        hz = city.horizon
        start = hz.start_s(hz.local_start(target).date())
        templates = tuple(
            TaskTemplate(str(t.id), int(t.node), float(t.scheduled_at_s - start))
            for t in self.service.registered_tasks(city.name)
            if 0.0 <= t.scheduled_at_s - start < hz.length_s
        )
        if templates:
            return TaskSet("registered", templates)
        return TaskSet("synthetic_per_day" if self.config.vary_tasks else "synthetic", None)

    def jobs(
        self, city: City, window: HistoryWindow, tasks: TaskSet | None = None
    ) -> dict[tuple[int, int], RunJob]:
        """One whole-day job per (size, day index), every day with the same tasks (unless they vary)."""
        cfg = self.config
        ts = tasks or TaskSet("synthetic_per_day" if cfg.vary_tasks else "synthetic", None)
        bundle = self.cities.bundle_dir(city.name)
        out: dict[tuple[int, int], RunJob] = {}
        for x in cfg.sizes:
            for i, day in enumerate(window.days):
                spec = RunSpec(
                    city=city.name,
                    n1=x,
                    n0=cfg.n0,
                    seed=cfg.seed,
                    day=day.spec_day,
                    n_tasks=cfg.n_tasks if ts.templates is None else len(ts.templates),
                    rate_per_hour=cfg.rate_per_hour if day.demand is None else None,
                    tasks_day=0 if ts.source == "synthetic" else None,
                )
                out[(x, i)] = RunJob(spec, bundle, day.demand, ts.templates)
        return out

    # ------------------------------------------------------------------ the solve

    def compute(
        self,
        city: City,
        target: IntervalKey,
        *,
        trigger: Literal["schedule", "request"],
        request_id: str | None,
    ) -> Recommendation:
        """Simulate and decide; ``SolveFailed`` with the reason when it cannot."""
        cfg = self.config
        window = self.window(city, target)
        tasks = self.task_set(city, target)
        observed = observed_today(self.service, city, target, self.clock())
        jobs = self.jobs(city, window, tasks)
        try:
            batch = self.runner.run(list(jobs.values()), self.progress)
        except ExecutorUnavailable as exc:
            raise SolveFailed(f"no run could start: {exc}") from exc
        if batch.failures:
            shown = "; ".join(f"{k}: {v}" for k, v in sorted(batch.failures.items())[:3])
            raise SolveFailed(f"{len(batch.failures)} of {len(jobs)} runs failed (partial solve): {shown}")
        res: dict[tuple[int, int], RunResult] = {key: batch.results[job.key] for key, job in jobs.items()}
        n_days = len(window.days)
        runs = {x: [res[(x, i)] for i in range(n_days)] for x in cfg.sizes}
        tau = city.horizon.interval_s / 3600.0
        volumes = hourly_volumes(runs[cfg.sizes[0]])
        try:
            outcomes = {x: day_outcomes(r, city.horizon, cfg.reach_s) for x, r in runs.items()}
            plan = plan_fleet(
                outcomes,
                volumes,
                cfg.ambiguity,
                CostModel(cfg.subsidy_cny_per_vehicle_hour, tau),
                observed=observed.requests_per_hour,
                keep=cfg.rolling_days,
                target=cfg.completion_target,
            )
            hour = city.horizon.position(target)
            zeta = cfg.subsidy_cny_per_vehicle_hour
            others = subsidy_sweep(  # the configured subsidy's point is the plan's own
                outcomes,
                volumes,
                [z for z in cfg.subsidy_sweep if z != zeta],
                hour=hour,
                ambiguity=cfg.ambiguity,
                interval_hours=tau,
                observed=observed.requests_per_hour,
                keep=cfg.rolling_days,
                target=cfg.completion_target,
            )
            sweep = tuple(sorted((*others, plan.point(hour)), key=lambda p: p.subsidy_cny_per_vehicle_hour))
        except ValueError as exc:
            raise SolveFailed(f"fleet sizing rejected the samples: {exc}") from exc
        requests = tuple(r.n_requests for r in runs[cfg.sizes[0]])
        stats = SolveStats(len(batch.results), batch.cached, batch.wall_s, self.runner.workers)
        return Recommendation(
            city,
            target,
            plan,
            cfg,
            window,
            requests,
            stats,
            trigger,
            request_id,
            observed,
            tasks,
            sweep=sweep,
        )

    def solve(
        self, city_name: str, target: IntervalKey, *, request: SolveRequest | None = None, force: bool = False
    ) -> SolveOutcome:
        """Solve hour ``target`` under its store lock and publish; ``force`` (and every admin request) solves
        even when the current recommendation already covers that hour."""
        started = time.perf_counter()
        request_id = None if request is None else request.request_id
        with self.service.hour_lock(city_name, target) as held:
            if not held:
                return SolveOutcome(city_name, target, "busy", request_id=request_id)
            current = self.service.current(city_name)
            if current is not None and current.interval == target and not (force or request is not None):
                return SolveOutcome(city_name, target, "skipped", version=current.version)
            expected = 0 if current is None or current.version is None else current.version
            trigger: Literal["schedule", "request"] = "schedule" if request is None else "request"
            try:
                city = self.load_city(city_name)
                rec = self.compute(city, target, trigger=trigger, request_id=request_id)
                body_json = self.render(rec)
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
                body_json=body_json,
                request_id=request_id,
            )
            result = self.service.publish(city_name, record)
            if result.status != "published":
                reason = f"superseded: version {result.version} was published while this solve ran"
                return self._fail(city_name, target, reason, request_id, started)
            wall = time.perf_counter() - started
            log.info(
                "fleet %s, hour %s: published version %d (deterministic %d, DRO %d, DRO_RH %d) in %.1f s",
                city_name,
                city.horizon.label(target),
                result.version,
                rec.plan.deterministic.size,
                rec.plan.dro.size,
                rec.plan.rolling[rec.position].choice.size,
                wall,
            )
            return SolveOutcome(city_name, target, "published", result.version, None, request_id, wall)

    def _fail(
        self, city: str, target: IntervalKey, reason: str, request_id: str | None, started: float
    ) -> SolveOutcome:
        """Record a failed solve in the history (the current recommendation stays) and log it."""
        reason = reason[:_MAX_REASON]
        log.error(
            "fleet %s, interval %d: solve failed, last good recommendation kept: %s", city, target, reason
        )
        record = FleetRecord("failed", self.clock(), int(target), reason=reason, request_id=request_id)
        self.service.record_failure(city, record)
        return SolveOutcome(city, target, "failed", None, reason, request_id, time.perf_counter() - started)
