"""The fleet solve (docs/FLEET.md): the coming hour of a city, sized on the platform's history and published.

One solve: check that the city can be sized (M recorded days, or the seeded synthetic history of a demo
city; the platform's tasks), pick the history window (the last M local days with epochs, each with its
requests and the fleet it ran), resolve the city's sizing configuration (its ``city.json`` ``fleet``
block, else derived from the fleet the platform posted, else the worker's settings), simulate every
(size, day) as a whole day from where that day's fleet stood when the horizon opened, form the KPI samples of
the platform's total cost per hour (DRO_RH conditioned on the hours the day has shown), call
:func:`services.fleet.sizing.plan_fleet` and the subsidy sweep, and publish the recommendation with the next
version under the hour's lock. Every failure -- a run that raised, bad samples, a lost version race --
keeps the current recommendation and is recorded in the history with its reason; a city that cannot be
sized yet starts no run at all (``NotReady``).

The worker (``app.worker``) decides when to solve, beats, and hands this use case the store (through the
port), the runner of the simulations and the renderer of the published document.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from app.ports import FleetRecord, SolveRequest, WorkerBeat, WorkerStore
from app.runs import ExecutorUnavailable, ProgressFn, RunBatch, RunJob, RunResult, RunSpec, TaskTemplate
from app.runs.outcomes import day_outcomes, hourly_volumes
from app.runs.runner import CallFailed
from app.usecases.cities import CityCatalog
from app.usecases.fleet_history import (
    DemandLog,
    FleetHistory,
    HistoryState,
    RecordedDay,
    SizingConfig,
    demand_from_records,
    posted_fleet,
    recorded_days,
    spread_sizes,
    start_nodes,
)
from services.city import City
from services.fleet.sizing import (
    Ambiguity,
    CostModel,
    DayOutcomes,
    FleetPlan,
    SubsidyPoint,
    plan_fleet,
    subsidy_sweep,
)
from services.model import IntervalKey, Task
from services.sim.demand import DemandSet

__all__ = [
    "OBJECTIVE",
    "BundleCatalog",
    "RunnerPort",
    "FleetOrigin",
    "HistoryDay",
    "HistoryWindow",
    "TaskSet",
    "Observed",
    "SolveStats",
    "Recommendation",
    "RecommendationRenderer",
    "SolveOutcome",
    "SolveFailed",
    "NotReady",
    "FleetSolver",
    "observed_today",
    "lock_name",
]

log = logging.getLogger(__name__)

OBJECTIVE = (
    "total platform cost per hour, CNY: 1.5 CNY/km x Step 3 km per hour + subsidy x N1 "
    "(docs/METHOD.md section 7); the per-vehicle design KPI is reported, not minimized"
)
_MAX_REASON = 2000


def lock_name(interval: int) -> str:
    """The store lock of one hour's solve."""
    return f"fleet-solve:{int(interval)}"


@runtime_checkable
class BundleCatalog(CityCatalog, Protocol):
    """The served cities and where each one's bundle lies (the runs read it;
    ``app.adapters.city_registry.CityRegistry``)."""

    def bundle_dir(self, name: str) -> Path:
        """The directory of the city's bundle."""
        ...


class RunnerPort(Protocol):
    """Where the simulation runs of a solve execute (``app.runs.Runner``)."""

    @property
    def workers(self) -> int:
        """How many runs execute at once."""
        ...

    def run(self, jobs: Sequence[RunJob], progress: ProgressFn | None = None) -> RunBatch:
        """Every job's result or the reason it failed."""
        ...

    def call(self, fn: Callable[[PlanInputs], PlanOutcome], item: PlanInputs) -> PlanOutcome:
        """``fn(item)`` where the runs execute (``CallFailed`` when it raised)."""
        ...


@dataclass(frozen=True, slots=True)
class FleetOrigin:
    """Where a solve's fleet came from: its candidate sizes and N0 (``city``: the city's ``city.json``;
    ``recorded``: derived from the fleet the platform posted; ``settings``: the worker's settings), the
    fleet posted over the history days (median per day; ``None`` on a synthetic history) and where the
    simulated taxis start (``recorded``: where the day's taxis stood when its horizon opened; ``seeded``:
    seeded random nodes)."""

    sizes: Literal["city", "recorded", "settings"]
    n0: Literal["city", "recorded", "settings"]
    posted_instrumented: int | None
    posted_ordinary: int | None
    starts: Literal["recorded", "seeded"]


@dataclass(frozen=True, slots=True)
class HistoryDay:
    """One demand sample: its label, the ``RunSpec`` day (seeds tasks; the generator's day when synthetic),
    the recorded day (``None``: synthetic)."""

    label: str
    spec_day: int
    recorded: RecordedDay | None

    @property
    def demand(self) -> DemandSet | None:
        """The recorded requests (``None``: the generator's)."""
        return None if self.recorded is None else self.recorded.demand


@dataclass(frozen=True, slots=True)
class HistoryWindow:
    """The M demand days of a solve and where they came from."""

    source: Literal["recorded", "synthetic"]
    days: tuple[HistoryDay, ...]
    recorded_available: int
    note: str


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
    ``fleet`` where the sizes, N0 and the taxis' starts came from; ``sweep`` every method's choice at the
    configured subsidy and the sweep's others (the trade-off curve).
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
    fleet: FleetOrigin
    objective: str = OBJECTIVE
    sweep: tuple[SubsidyPoint, ...] = ()

    @property
    def position(self) -> int:
        """Hour of the horizon solved for, 0-based."""
        return self.city.horizon.position(self.target)


RecommendationRenderer = Callable[[Recommendation], str]
"""The published document of a recommendation (the API serves it with its version and publication time)."""


@dataclass(frozen=True, slots=True)
class SolveOutcome:
    """What one solve attempt did: ``published`` (``version``), ``failed`` (``reason``, recorded in the
    history), ``waiting`` (the city cannot be sized yet: ``reason``, ``waiting_for`` the ``NotReady`` kind;
    no run started; recorded in the history for a request only), ``skipped`` (the hour was already solved)
    or ``busy`` (another worker holds its lock)."""

    city: str
    interval: int
    status: Literal["published", "failed", "waiting", "skipped", "busy"]
    version: int | None = None
    reason: str | None = None
    request_id: str | None = None
    wall_s: float = 0.0
    waiting_for: str | None = None


class SolveFailed(RuntimeError):
    """A solve could not produce a recommendation (the message is the reason recorded in the history)."""


class NotReady(SolveFailed):
    """The city cannot be sized now, for a reason that does not change by itself (``kind``:
    ``insufficient_history`` until M days are recorded, ``no_tasks`` until the platform registers tasks);
    found before any run starts."""

    def __init__(self, kind: Literal["insufficient_history", "no_tasks"], reason: str) -> None:
        super().__init__(reason)
        self.kind = kind


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
    for r in demand_from_records(city, day, records).requests:
        i = int((r.time_s - start) // hz.interval_s)
        if 0 <= i < past:
            counts[i] += 1
    return Observed(day.isoformat(), tuple(counts))


class FleetSolver:
    """The fleet worker's use case: solve requests, solving and publishing, and its heartbeat's record.

    ``history_limit`` bounds a city's recommendation history; ``lock_ttl_s`` is how long an hour's lock
    outlives a worker that died holding it. ``progress`` sees the runs of every solve start and finish.
    """

    def __init__(
        self,
        store: WorkerStore,
        runner: RunnerPort,
        defaults: SizingConfig,
        *,
        render: RecommendationRenderer,
        cities: BundleCatalog,
        clock: Callable[[], float] = time.time,
        progress: ProgressFn | None = None,
        history_limit: int = 100,
        lock_ttl_s: float = 1800.0,
    ) -> None:
        self.store = store
        self.runner = runner
        self.history = FleetHistory(store, defaults)
        self.render = render
        self.cities = cities
        self.clock = clock
        self.progress = progress
        self.history_limit = history_limit
        self.lock_ttl_s = lock_ttl_s

    @property
    def defaults(self) -> SizingConfig:
        """The worker's settings (a city's own values go on top)."""
        return self.history.defaults

    def load_city(self, name: str) -> City:
        """The city (``app.errors.UnknownCity`` when the catalog does not serve it)."""
        return self.cities.get(name)

    # ------------------------------------------------------------------ requests and heartbeat

    def claim_request(self, city: str) -> SolveRequest | None:
        """Take the city's pending admin request off the queue, if any (exactly one worker gets it)."""
        return self.store.claim_solve_request(city)

    def requeue(self, city: str, request: SolveRequest) -> None:
        """Put a claimed request back for the next poll (another worker holds the hour's lock)."""
        self.store.enqueue_solve_request(city, request)

    def beat(self, city: str, beat: WorkerBeat, keep_s: float) -> None:
        """Record the worker's latest beat for the city (beats older than ``keep_s`` are dropped)."""
        self.store.record_worker_beat(city, beat, keep_s)

    # ------------------------------------------------------------------ inputs

    def registered_tasks(self, city: str) -> list[Task]:
        """The platform's registered tasks of the city, in scheduled order."""
        return sorted(self.store.list_tasks(city), key=lambda t: (t.scheduled_at_s, str(t.id)))

    def task_set(self, city: City, target: IntervalKey, cfg: SizingConfig) -> TaskSet:
        """The platform's registered tasks scheduled within the horizon of the target's day, as templates;
        without any, the seeded synthetic draw on a demo city (``NotReady`` on any other)."""
        hz = city.horizon
        day = hz.local_start(target).date()
        start = hz.start_s(day)
        templates = tuple(
            TaskTemplate(str(t.id), int(t.node), float(t.scheduled_at_s - start))
            for t in self.registered_tasks(city.name)
            if 0.0 <= t.scheduled_at_s - start < hz.length_s
        )
        if templates:
            return TaskSet("registered", templates)
        if not city.fleet.synthetic_history:
            raise NotReady(
                "no_tasks",
                f"no monitoring task of {city.name!r} is scheduled within the horizon of {day}: the "
                "simulated days carry the platform's tasks; register them (POST .../tasks) and solve again",
            )
        return TaskSet("synthetic_per_day" if cfg.vary_tasks else "synthetic", None)

    def window(self, city: City, target: IntervalKey, cfg: SizingConfig) -> HistoryWindow:
        """The last M local days with epochs before the target hour's date; with fewer, the seeded synthetic
        days on a demo city (``NotReady`` on any other)."""
        day = city.horizon.local_start(target).date()
        found = recorded_days(self.history, city, day, cfg.days, cfg.lookback_days)
        if len(found) >= cfg.days:
            return HistoryWindow(
                "recorded",
                tuple(HistoryDay(d.date.isoformat(), d.date.toordinal(), d) for d in found),
                len(found),
                f"the {cfg.days} most recent local days with epochs before {day}",
            )
        state = HistoryState(day, len(found), cfg.days, cfg.lookback_days)
        if not city.fleet.synthetic_history:
            raise NotReady("insufficient_history", state.describe())
        return HistoryWindow(
            "synthetic",
            tuple(HistoryDay(f"synthetic-{d}", d, None) for d in range(1, cfg.days + 1)),
            len(found),
            f"{len(found)} day(s) with epochs in the {cfg.lookback_days} days before {day}, fewer than "
            f"M = {cfg.days}: seeded synthetic history, days 1..{cfg.days} of the city's generator "
            f"(seed {cfg.seed})",
        )

    def fleet_config(
        self, city: City, window: HistoryWindow, cfg: SizingConfig
    ) -> tuple[SizingConfig, FleetOrigin]:
        """The sizes and N0 of the solve: the city's when set, else derived from the fleet posted over the
        recorded days (N0 the ordinary fleet, the sizes :func:`spread_sizes` of the instrumented one), else
        the settings'."""
        params = city.fleet
        recorded = [d.recorded for d in window.days if d.recorded is not None]
        posted = posted_fleet(recorded)
        sizes_from: Literal["city", "recorded", "settings"] = "settings"
        n0_from: Literal["city", "recorded", "settings"] = "settings"
        if params.sizes is not None:
            sizes_from = "city"
        elif posted is not None and posted[0] >= 1:
            cfg, sizes_from = replace(cfg, sizes=spread_sizes(posted[0])), "recorded"
        if params.n0 is not None:
            n0_from = "city"
        elif posted is not None:
            cfg, n0_from = replace(cfg, n0=posted[1]), "recorded"
        starts: Literal["recorded", "seeded"] = (
            "recorded"
            if recorded
            and all(d.fleet is not None and d.fleet.instrumented_nodes is not None for d in recorded)
            else "seeded"
        )
        origin = FleetOrigin(
            sizes_from,
            n0_from,
            None if posted is None else posted[0],
            None if posted is None else posted[1],
            starts,
        )
        return cfg, origin

    def jobs(
        self, city: City, window: HistoryWindow, cfg: SizingConfig, tasks: TaskSet | None = None
    ) -> dict[tuple[int, int], RunJob]:
        """One whole-day job per (size, day index), every day with the same tasks (unless they vary), its
        taxis starting where the day's fleet stood when the horizon opened (when recorded)."""
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
                starts = None
                if day.recorded is not None and day.recorded.fleet is not None:
                    nodes = start_nodes(day.recorded.fleet, day.recorded.date, x, cfg.n0, cfg.seed)
                    starts = None if nodes is None else tuple(int(v) for v in nodes)
                out[(x, i)] = RunJob(spec, bundle, day.demand, ts.templates, starts)
        return out

    # ------------------------------------------------------------------ the solve

    def check(self, city: City, target: IntervalKey) -> None:
        """Raise ``NotReady`` when the city cannot be sized for ``target`` (without reading any record)."""
        cfg = self.history.config(city)
        if not city.fleet.synthetic_history:
            state = self.history.state(city, city.horizon.local_start(target).date())
            if not state.enough:
                raise NotReady("insufficient_history", state.describe())
        self.task_set(city, target, cfg)

    def compute(
        self,
        city: City,
        target: IntervalKey,
        *,
        trigger: Literal["schedule", "request"],
        request_id: str | None,
    ) -> Recommendation:
        """Simulate and decide; ``SolveFailed`` (``NotReady`` before any run) with the reason when it
        cannot."""
        cfg = self.history.config(city)
        tasks = self.task_set(city, target, cfg)
        window = self.window(city, target, cfg)
        cfg, origin = self.fleet_config(city, window, cfg)
        observed = observed_today(self.history, city, target, self.clock())
        jobs = self.jobs(city, window, cfg, tasks)
        try:
            batch = self.runner.run(list(jobs.values()), self.progress)
        except ExecutorUnavailable as exc:
            raise SolveFailed(f"no run could start: {exc}") from exc
        if batch.failures:
            shown = "; ".join(f"{k}: {v}" for k, v in sorted(batch.failures.items())[:3])
            raise SolveFailed(f"{len(batch.failures)} of {len(jobs)} runs failed (partial solve): {shown}")
        res: dict[tuple[int, int], RunResult] = {key: batch.results[job.key] for key, job in jobs.items()}
        runs = {x: [res[(x, i)] for i in range(len(window.days))] for x in cfg.sizes}
        plan, sweep = self._plan(city, target, cfg, runs, observed)
        stats = SolveStats(len(batch.results), batch.cached, batch.wall_s, self.runner.workers)
        requests = tuple(r.n_requests for r in runs[cfg.sizes[0]])
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
            origin,
            sweep=sweep,
        )

    def _plan(
        self,
        city: City,
        target: IntervalKey,
        cfg: SizingConfig,
        runs: dict[int, list[RunResult]],
        observed: Observed,
    ) -> tuple[FleetPlan, tuple[SubsidyPoint, ...]]:
        """The plan at the configured subsidy and the sweep's other subsidies, from the runs: decided where
        the runs go (``Runner.call``), so that a service embedding the worker pauses it with them while its
        epochs are solved instead of sharing its interpreter with them; here when it cannot run there (a
        solve whose runs were all cached publishes without its cluster)."""
        tau = city.horizon.interval_s / 3600.0
        hour = city.horizon.position(target)
        zeta = cfg.subsidy_cny_per_vehicle_hour
        try:
            inputs = PlanInputs(
                {x: day_outcomes(r, city.horizon, cfg.reach_s) for x, r in runs.items()},
                hourly_volumes(runs[cfg.sizes[0]]),
                cfg.ambiguity,
                CostModel(zeta, tau),
                tuple(z for z in cfg.subsidy_sweep if z != zeta),  # the configured one's point is the plan's
                hour,
                observed.requests_per_hour,
                cfg.rolling_days,
                cfg.completion_target,
            )
        except ValueError as exc:
            raise SolveFailed(f"fleet sizing rejected the samples: {exc}") from exc
        try:
            got = self.runner.call(plan_and_sweep, inputs)
        except (CallFailed, ExecutorUnavailable) as exc:  # e.g. a cluster lost after its runs: size here
            log.warning(
                "fleet %s: the sizing could not run where the runs go (%s); sized here", city.name, exc
            )
            got = plan_and_sweep(inputs)
        if isinstance(got, str):
            raise SolveFailed(f"fleet sizing rejected the samples: {got}")
        plan, others = got
        sweep = tuple(sorted((*others, plan.point(hour)), key=lambda p: p.subsidy_cny_per_vehicle_hour))
        return plan, sweep

    @contextmanager
    def hour_lock(self, city: str, target: IntervalKey) -> Iterator[bool]:
        """Hold the lock of hour ``target``'s solve for the block: yields whether it was taken (``False``:
        another worker holds it, and nothing is to be written)."""
        token = self.store.acquire_lock(city, lock_name(target), self.lock_ttl_s)
        try:
            yield token is not None
        finally:
            if token is not None:
                self.store.release_lock(city, lock_name(target), token)

    def solve(
        self, city_name: str, target: IntervalKey, *, request: SolveRequest | None = None, force: bool = False
    ) -> SolveOutcome:
        """Solve hour ``target`` under its store lock and publish; ``force`` (and every admin request) solves
        even when the current recommendation already covers that hour. A city that cannot be sized yet
        starts no run: ``waiting`` (recorded in the history only for a request, whose asker looks there)."""
        started = time.perf_counter()
        request_id = None if request is None else request.request_id
        with self.hour_lock(city_name, target) as held:
            if not held:
                return SolveOutcome(city_name, target, "busy", request_id=request_id)
            current = self.store.current_recommendation(city_name)
            if current is not None and current.interval == target and not (force or request is not None):
                return SolveOutcome(city_name, target, "skipped", version=current.version)
            expected = 0 if current is None or current.version is None else current.version
            trigger: Literal["schedule", "request"] = "schedule" if request is None else "request"
            try:
                city = self.load_city(city_name)
                self.check(city, target)
                rec = self.compute(city, target, trigger=trigger, request_id=request_id)
                body_json = self.render(rec)
            except NotReady as exc:
                reason = str(exc)[:_MAX_REASON]
                if request is not None:  # its asker reads the history
                    self._record_failure(city_name, target, reason, request_id)
                wall = time.perf_counter() - started
                return SolveOutcome(city_name, target, "waiting", None, reason, request_id, wall, exc.kind)
            except Exception as exc:  # noqa: BLE001 - any failure keeps the last good recommendation
                if not isinstance(exc, SolveFailed):
                    log.exception("fleet solve of %s for interval %d raised", city_name, target)
                reason = str(exc) if isinstance(exc, SolveFailed) else f"{type(exc).__name__}: {exc}"
                return self._fail(city_name, target, reason, request_id, started)
            return self._publish(city, target, rec, body_json, expected, request_id, started)

    def _publish(
        self,
        city: City,
        target: IntervalKey,
        rec: Recommendation,
        body_json: str,
        expected: int,
        request_id: str | None,
        started: float,
    ) -> SolveOutcome:
        """Publish the recommendation as the next version (a lost race is a failure in the history)."""
        record = FleetRecord(
            "published",
            self.clock(),
            int(target),
            version=expected + 1,
            body_json=body_json,
            request_id=request_id,
        )
        result = self.store.publish_recommendation(city.name, record, self.history_limit)
        if result.status != "published":
            reason = f"superseded: version {result.version} was published while this solve ran"
            return self._fail(city.name, target, reason, request_id, started)
        wall = time.perf_counter() - started
        log.info(
            "fleet %s, hour %s: published version %d (deterministic %d, DRO %d, DRO_RH %d) in %.1f s",
            city.name,
            city.horizon.label(target),
            result.version,
            rec.plan.deterministic.size,
            rec.plan.dro.size,
            rec.plan.rolling[rec.position].choice.size,
            wall,
        )
        return SolveOutcome(city.name, target, "published", result.version, None, request_id, wall)

    def _fail(
        self, city: str, target: IntervalKey, reason: str, request_id: str | None, started: float
    ) -> SolveOutcome:
        """Record a failed solve in the history (the current recommendation stays) and log it."""
        reason = reason[:_MAX_REASON]
        log.error(
            "fleet %s, interval %d: solve failed, last good recommendation kept: %s", city, target, reason
        )
        self._record_failure(city, target, reason, request_id)
        return SolveOutcome(city, target, "failed", None, reason, request_id, time.perf_counter() - started)

    def _record_failure(self, city: str, target: IntervalKey, reason: str, request_id: str | None) -> None:
        record = FleetRecord("failed", self.clock(), int(target), reason=reason, request_id=request_id)
        self.store.record_solve_failure(city, record, self.history_limit)


@dataclass(frozen=True, slots=True)
class PlanInputs:
    """What one solve's sizing reads, sent whole to where the runs go (``plan_and_sweep``): the day outcomes
    per fleet size, the requests per interval of the first size's days, the ambiguity set, the cost model
    at the configured subsidy, the sweep's other subsidies, the target interval's position in the day, the
    requests observed so far today, the days kept for the rolling horizon and the completion target."""

    outcomes: dict[int, DayOutcomes]
    volumes: NDArray[np.float64]
    ambiguity: Ambiguity
    costs: CostModel
    others: tuple[float, ...]
    hour: int
    observed: tuple[int, ...]
    keep: int
    target: float | None


PlanOutcome = tuple[FleetPlan, tuple[SubsidyPoint, ...]] | str
"""``plan_and_sweep``'s: the plan and the sweep's other points, or why the samples were rejected."""


def plan_and_sweep(inputs: PlanInputs) -> PlanOutcome:
    """``plan_fleet`` at the configured subsidy and ``subsidy_sweep`` at the others; the message when the
    samples are rejected (a ``ValueError`` of the sizing), so that the solve can say so."""
    try:
        plan = plan_fleet(
            inputs.outcomes,
            inputs.volumes,
            inputs.ambiguity,
            inputs.costs,
            observed=inputs.observed,
            keep=inputs.keep,
            target=inputs.target,
        )
        others = subsidy_sweep(
            inputs.outcomes,
            inputs.volumes,
            list(inputs.others),
            hour=inputs.hour,
            ambiguity=inputs.ambiguity,
            interval_hours=inputs.costs.interval_hours,
            observed=inputs.observed,
            keep=inputs.keep,
            target=inputs.target,
        )
    except ValueError as exc:
        return str(exc)
    return plan, others
