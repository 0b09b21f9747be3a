"""Response models of the fleet-sizing API (docs/FLEET.md) and their conversion from
``services.fleet.sizing``.

The fleet solve's result (``app.usecases.fleet_solve.Recommendation``) is published as the JSON of
:class:`RecommendationBody` (``render_recommendation``, which the worker hands the use case); the API adds
the store's version and publication time and serves it as :class:`FleetRecommendationOut`.
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any, Literal, Self

from pydantic import Field

from app.ports import FleetRecord
from app.schemas.common import ResponseModel
from services.city import Horizon
from services.fleet.sizing import CandidateTable, Choice, RollingHour, SubsidyPoint
from services.rfc3339 import format_time

if TYPE_CHECKING:  # the simulation runs' machinery stays out of the API process
    from app.usecases.fleet_solve import Recommendation, SolveStats

__all__ = [
    "CandidateOut",
    "ChoiceOut",
    "HourChoiceOut",
    "ChosenOut",
    "DataWindowOut",
    "ObservedOut",
    "SimulationOut",
    "SolveStatsOut",
    "SubsidyPointOut",
    "subsidy_note",
    "RecommendationBody",
    "FleetRecommendationOut",
    "SolveEntryOut",
    "FleetHistoryEntryOut",
    "FleetHistoryOut",
    "SolveRequestOut",
    "candidates_out",
    "recommendation_body",
    "render_recommendation",
]


Method = Literal["deterministic", "dro", "box_lp", "dro_rh"]


class CandidateOut(ResponseModel):
    """One candidate fleet size: what it costs the platform per hour, per vehicle, and what it completes."""

    size: int = Field(description="Instrumented fleet size N1.")
    n_samples: int = Field(description="Demand days behind the row.")
    mean_cost_cny_per_h: float = Field(description="Sample mean of the total cost per hour (Step 3 + ζ N1).")
    worst_case_cost_cny_per_h: float = Field(description="Its worst-case expectation over the ball (exact).")
    premium_cny_per_h: float = Field(description="worst case - mean.")
    box_lp_worst_case_cny_per_h: float | None = Field(
        description="The paper's box LP (Eq. 28) worst case, an outer approximation (null: samples support)."
    )
    rho: float = Field(description="Radius of the ball.")
    m: int = Field(description="Cells of the empirical distribution.")
    status: str = Field(description="The exact worst-case solve's status: optimal, saturated or degenerate.")
    design_kpi_mean: float = Field(description="Per-vehicle design KPI: mean total cost per hour / N1.")
    design_kpi_worst_case: float = Field(description="Worst-case total cost per hour / N1.")
    completion_mean: float | None = Field(description="Mean completion rate of the reachable POI tasks.")
    completion_worst_case: float | None = Field(description="Its worst case (infimum over the ball).")
    picked_by: list[Method] = Field(description="The methods that choose this size.")
    samples: list[float] = Field(
        description="The total cost per hour on each day of `days`, in that order: the decision's samples."
    )
    completion_samples: list[float] | None = Field(description="Completion rate on each day of `days`.")


def candidates_out(table: CandidateTable, picks: dict[int, list[Method]]) -> list[CandidateOut]:
    """A table's rows, ascending size, with the samples and the methods that pick each size."""
    out = []
    for r in table.rows:
        comp = table.completion_samples
        out.append(
            CandidateOut(
                size=r.size,
                n_samples=r.cost.n_samples,
                mean_cost_cny_per_h=r.cost.mean,
                worst_case_cost_cny_per_h=r.cost.worst_case,
                premium_cny_per_h=r.cost.premium,
                box_lp_worst_case_cny_per_h=None if math.isnan(r.box_lp_worst_case) else r.box_lp_worst_case,
                rho=r.cost.rho,
                m=r.cost.m,
                status=r.cost.status,
                design_kpi_mean=r.design_kpi_mean,
                design_kpi_worst_case=r.design_kpi_worst_case,
                completion_mean=None if r.completion is None else r.completion.mean,
                completion_worst_case=None if r.completion is None else r.completion.worst_case,
                picked_by=picks.get(r.size, []),
                samples=[float(v) for v in table.cost_samples[r.size]],
                completion_samples=None if comp is None else [float(v) for v in comp[r.size]],
            )
        )
    return out


class ChoiceOut(ResponseModel):
    """A method's chosen size: its objective (mean or worst-case total cost per hour) and ties."""

    size: int
    objective: float = Field(description="The minimized value, CNY per hour.")
    tied: list[int] = Field(description="Sizes whose objective ties the optimum; the smallest is chosen.")
    status: Literal["unique", "tie"]
    target_met: bool | None = Field(
        description="With a completion target: whether the size meets it (false: no size does, the best "
        "completion was taken). Null without a target."
    )

    @classmethod
    def of(cls, choice: Choice) -> ChoiceOut:
        """From the core's choice."""
        return cls(
            size=choice.size,
            objective=choice.objective,
            tied=list(choice.tied),
            status=choice.status,
            target_met=choice.target_met,
        )


class HourChoiceOut(ChoiceOut):
    """DRO_RH for one hour: conditioned on the hours of the day observed, on the history days kept."""

    interval: str = Field(description="Local start of the hour, YYYY-MM-DDTHH:MM.")
    position: int = Field(description="Hour of the horizon, 0-based.")
    observed_hours: int = Field(description="Hours of the day whose recorded demand conditioned this choice.")
    days: list[str] = Field(
        description="The history days kept (closest hourly volumes), labels as data_window."
    )
    candidates: list[CandidateOut] = Field(description="This hour's total cost per size on the kept days.")


class ChosenOut(ResponseModel):
    """The chosen size per method."""

    deterministic: int = Field(description="Argmin of the mean total cost per hour.")
    dro: int = Field(description="Argmin of its worst case (one size for the day).")
    box_lp: int = Field(description="Argmin of the paper's box LP worst case (Eq. 28), for comparison.")
    dro_rh: int = Field(description="DRO_RH's size for the coming hour.")


class ObservedOut(ResponseModel):
    """What the day being sized has shown so far: the recorded requests of its hours already past."""

    date: str = Field(description="Local date of the hour solved for.")
    hours: int = Field(description="Whole hours of the horizon already past when solving.")
    requests_per_hour: list[int] = Field(description="Recorded requests in each of those hours.")


class DataWindowOut(ResponseModel):
    """Which days of demand the samples come from."""

    source: Literal["recorded", "synthetic"]
    days: list[str] = Field(
        description="Recorded: local dates YYYY-MM-DD, newest first. Synthetic: 'synthetic-<d>' for the "
        "seeded generator's day d."
    )
    n_days: int
    requests_per_day: list[int]
    recorded_days_available: int = Field(description="Days with recorded demand found in the look-back.")
    seed: int | None = Field(description="Seed of the synthetic history (null for recorded demand).")
    note: str


class SimulationOut(ResponseModel):
    """How each (size, day) run was simulated."""

    n0: int = Field(description="Ordinary taxis.")
    n0_source: Literal["city", "recorded", "settings"] = Field(
        default="settings",
        description="Where n0 came from: the city's city.json, the ordinary fleet the platform posted "
        "(median over the history days), or SD_WORKER_N0.",
    )
    sizes_source: Literal["city", "recorded", "settings"] = Field(
        default="settings",
        description="Where the candidate sizes came from: the city's city.json, spread from a quarter to "
        "twice the instrumented fleet the platform posted (median over the history days), or "
        "SD_WORKER_SIZES.",
    )
    posted_instrumented: int | None = Field(
        default=None,
        description="Instrumented taxis the platform posted, median over the history days (null: synthetic "
        "history).",
    )
    posted_ordinary: int | None = Field(
        default=None, description="Ordinary taxis the platform posted, likewise."
    )
    fleet_start: Literal["recorded", "seeded"] = Field(
        default="seeded",
        description="Where the simulated taxis start: where each history day's taxis stood when its horizon "
        "opened (recorded), or seeded random nodes.",
    )
    n_tasks: int = Field(description="POI monitoring tasks in every simulated day.")
    tasks_source: Literal["registered", "synthetic", "synthetic_per_day"] = Field(
        description="registered: the platform's tasks of the day solved for, in every simulated day; "
        "synthetic: one seeded set for every day; synthetic_per_day: redrawn each day (vary-tasks option)."
    )
    reach_s: float = Field(
        description="Tasks due this close to the horizon's end do not count for completion."
    )
    rate_per_hour: float | None = Field(description="Synthetic requests per hour (null: city default).")
    seed: int


class SolveStatsOut(ResponseModel):
    """What the solve cost."""

    runs: int
    cached_runs: int
    wall_s: float
    jobs: int

    @classmethod
    def of(cls, stats: SolveStats) -> SolveStatsOut:
        """From the worker's solve statistics."""
        return cls(runs=stats.runs, cached_runs=stats.cached_runs, wall_s=stats.wall_s, jobs=stats.jobs)


class SubsidyPointOut(ResponseModel):
    """Each method's choice had ζ been this value (same samples, same days, same conditioning)."""

    subsidy_cny_per_vehicle_hour: float
    deterministic: int
    dro: int
    dro_rh: int = Field(description="DRO_RH's size for the hour solved for.")
    dro_objective: float = Field(description="DRO's worst-case total cost per hour at its choice, CNY.")

    @classmethod
    def of(cls, point: SubsidyPoint) -> SubsidyPointOut:
        """From the core's sweep point."""
        return cls(
            subsidy_cny_per_vehicle_hour=point.subsidy_cny_per_vehicle_hour,
            deterministic=point.deterministic.size,
            dro=point.dro.size,
            dro_rh=point.dro_rh.size,
            dro_objective=point.dro.objective,
        )


def subsidy_note(subsidy: float, sweep: tuple[SubsidyPoint, ...]) -> str:
    """One sentence on how the choice depends on ζ: DRO's size over the sweep's range of subsidies."""
    head = (
        f"The sizes depend on the subsidy ζ = {subsidy:g} CNY per instrumented vehicle-hour "
        "(SD_WORKER_SUBSIDY_CNY_PER_VEHICLE_HOUR; its default, a sensor kit amortized over its service hours "
        "plus the driver incentive, is derived in docs/FLEET.md)"
    )
    if not sweep:
        return head + "."
    runs: list[tuple[int, float, float]] = []  # (DRO size, first ζ, last ζ) over the sweep, ascending ζ
    for p in sweep:
        z = p.subsidy_cny_per_vehicle_hour
        if runs and runs[-1][0] == p.dro.size:
            runs[-1] = (runs[-1][0], runs[-1][1], z)
        else:
            runs.append((p.dro.size, z, z))
    parts = [f"{x} at ζ = {a:g}" if a == b else f"{x} for ζ in [{a:g}, {b:g}]" for x, a, b in runs]
    return f"{head}: on these samples DRO picks " + ", ".join(parts) + " (subsidy_sweep)."


class RecommendationBody(ResponseModel):
    """A fleet-sizing recommendation as the worker publishes it."""

    city: str
    interval: str = Field(description="The hour solved for (local start, YYYY-MM-DDTHH:MM).")
    interval_start: str = Field(description="Its start, RFC 3339 in the city's time zone.")
    position: int = Field(description="Hour of the horizon, 0-based.")
    trigger: Literal["schedule", "request"]
    request_id: str | None
    objective: str = Field(description="What the methods minimize.")
    subsidy_cny_per_vehicle_hour: float = Field(description="ζ, the subsidy per instrumented vehicle-hour.")
    subsidy_note: str = Field(
        default="", description="How the choice depends on ζ (what DRO picks over subsidy_sweep)."
    )
    subsidy_sweep: list[SubsidyPointOut] = Field(
        default_factory=list,
        description="Each method's choice at a few subsidies (the configured ζ among them), from the same "
        "samples: the trade-off curve.",
    )
    completion_target: float | None = Field(
        description="Worst-case completion rate on reachable tasks every choice must meet (null: none)."
    )
    chosen: ChosenOut
    deterministic: ChoiceOut
    dro: ChoiceOut
    box_lp: ChoiceOut
    dro_rh: HourChoiceOut
    dro_rh_by_hour: list[HourChoiceOut] = Field(
        description="DRO_RH for every hour of the horizon, each conditioned on the hours observed so far "
        "(a past hour: on the hours before it)."
    )
    candidates: list[CandidateOut] = Field(
        description="The whole horizon per size (Deterministic's, DRO's and the box LP's table), on all days."
    )
    observed: ObservedOut
    divergence: str
    alpha: float
    support: Literal["binned", "samples"]
    bins: int
    sizes: list[int]
    data_window: DataWindowOut
    simulation: SimulationOut
    solve: SolveStatsOut


def _picks(methods: dict[Method, int]) -> dict[int, list[Method]]:
    """The methods that chose each size."""
    out: dict[int, list[Method]] = {}
    for m, x in methods.items():
        out.setdefault(x, []).append(m)
    return out


def _data_window(rec: Recommendation, labels: list[str]) -> DataWindowOut:
    """The demand days the recommendation was sized on."""
    window, cfg = rec.window, rec.config
    return DataWindowOut(
        source=window.source,
        days=labels,
        n_days=len(window.days),
        requests_per_day=list(rec.requests_per_day),
        recorded_days_available=window.recorded_available,
        seed=cfg.seed if window.source == "synthetic" else None,
        note=window.note,
    )


def _simulation(rec: Recommendation) -> SimulationOut:
    """The simulations' settings."""
    cfg, fleet = rec.config, rec.fleet
    return SimulationOut(
        n0=cfg.n0,
        n0_source=fleet.n0,
        sizes_source=fleet.sizes,
        posted_instrumented=fleet.posted_instrumented,
        posted_ordinary=fleet.posted_ordinary,
        fleet_start=fleet.starts,
        n_tasks=cfg.n_tasks if rec.tasks.templates is None else len(rec.tasks.templates),
        tasks_source=rec.tasks.source,
        reach_s=cfg.reach_s,
        rate_per_hour=cfg.rate_per_hour,
        seed=cfg.seed,
    )


def recommendation_body(rec: Recommendation) -> RecommendationBody:
    """The published document of a recommendation (the API adds version and computed_at)."""
    plan, cfg, window, hz = rec.plan, rec.config, rec.window, rec.city.horizon
    position = rec.position
    first = rec.target - position
    labels = [d.label for d in window.days]

    def hour(r: RollingHour) -> HourChoiceOut:
        base = ChoiceOut.of(r.choice).model_dump()
        return HourChoiceOut(
            **base,
            interval=hz.label(first + r.hour),
            position=r.hour,
            observed_hours=r.observed_hours,
            days=[labels[i] for i in r.table.days],
            candidates=candidates_out(r.table, _picks({"dro_rh": r.choice.size})),
        )

    by_hour = [hour(r) for r in plan.rolling]
    daily_picks: dict[Method, int] = {
        "deterministic": plan.deterministic.size,
        "dro": plan.dro.size,
        "box_lp": plan.box_lp.size,
    }
    observed = rec.observed
    return RecommendationBody(
        city=rec.city.name,
        interval=hz.label(rec.target),
        interval_start=format_time(hz.interval_start_s(rec.target), hz.timezone),
        position=position,
        trigger=rec.trigger,
        request_id=rec.request_id,
        objective=rec.objective,
        subsidy_cny_per_vehicle_hour=cfg.subsidy_cny_per_vehicle_hour,
        subsidy_note=subsidy_note(cfg.subsidy_cny_per_vehicle_hour, rec.sweep),
        subsidy_sweep=[SubsidyPointOut.of(p) for p in rec.sweep],
        completion_target=cfg.completion_target,
        chosen=ChosenOut(
            deterministic=plan.deterministic.size,
            dro=plan.dro.size,
            box_lp=plan.box_lp.size,
            dro_rh=plan.rolling[position].choice.size,
        ),
        deterministic=ChoiceOut.of(plan.deterministic),
        dro=ChoiceOut.of(plan.dro),
        box_lp=ChoiceOut.of(plan.box_lp),
        dro_rh=by_hour[position],
        dro_rh_by_hour=by_hour,
        candidates=candidates_out(plan.daily, _picks(daily_picks)),
        observed=ObservedOut(
            date=observed.date,
            hours=len(observed.requests_per_hour),
            requests_per_hour=list(observed.requests_per_hour),
        ),
        divergence=cfg.ambiguity.divergence,
        alpha=cfg.ambiguity.alpha,
        support=cfg.ambiguity.support,
        bins=cfg.ambiguity.bins,
        sizes=list(cfg.sizes),
        data_window=_data_window(rec, labels),
        simulation=_simulation(rec),
        solve=SolveStatsOut.of(rec.stats),
    )


def render_recommendation(rec: Recommendation) -> str:
    """The JSON the worker publishes for a recommendation (``FleetSizing``'s renderer)."""
    return recommendation_body(rec).model_dump_json()


class FleetRecommendationOut(RecommendationBody):
    """The current recommendation of a city."""

    version: int = Field(description="Monotonic per city: 1, 2, ...")
    computed_at: str = Field(description="When it was published, RFC 3339 in the city's time zone.")

    @classmethod
    def of(cls, record: FleetRecord, timezone: str) -> FleetRecommendationOut:
        """From a published record of the store."""
        if record.body_json is None or record.version is None:
            raise ValueError("not a published record")
        doc = json.loads(record.body_json)
        return cls(**doc, version=record.version, computed_at=format_time(record.computed_at_s, timezone))


class SolveEntryOut(ResponseModel):
    """A solve as the history keeps it (the fields ``FleetHistoryEntryOut`` and the status's last solve
    share)."""

    status: Literal["published", "failed"]
    computed_at: str
    interval: str
    version: int | None
    reason: str | None
    request_id: str | None

    @classmethod
    def of(cls, record: FleetRecord, horizon: Horizon, **extra: Any) -> Self:
        """From a record of the history, its times in the city's time zone; ``extra`` fills the subclass's
        own fields."""
        return cls(
            status=record.status,
            computed_at=format_time(record.computed_at_s, horizon.timezone),
            interval=horizon.label(record.interval),
            version=record.version,
            reason=record.reason,
            request_id=record.request_id,
            **extra,
        )


class FleetHistoryEntryOut(SolveEntryOut):
    """One solve: published (with its recommendation) or failed (with the reason)."""

    recommendation: FleetRecommendationOut | None


class FleetHistoryOut(ResponseModel):
    """Solves of a city, newest first."""

    city: str
    entries: list[FleetHistoryEntryOut]


class SolveRequestOut(ResponseModel):
    """A queued solve request (the worker picks it up within its poll interval)."""

    request_id: str = Field(description="Shows up as request_id in the history once solved.")
    city: str
    status: Literal["queued", "already_queued"] = Field(
        description="already_queued: a request was pending; this one joins it (same request_id)."
    )
    requested_at: str
