"""Response models of the fleet-sizing API (docs/FLEET.md) and their conversion from ``services.fleet``.

The worker stores a recommendation as the JSON of :class:`RecommendationBody`; the API adds the store's
version and publication time and serves it as :class:`FleetRecommendationOut`.
"""

from __future__ import annotations

import json
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from app.ports import FleetRecord
from app.schemas import format_time
from services.fleet import Choice, SizeRow, SizeTable, TargetChoice

__all__ = [
    "SizeRowOut",
    "ChoiceOut",
    "HourChoiceOut",
    "ChosenOut",
    "CompletionTargetOut",
    "DataWindowOut",
    "SimulationOut",
    "SolveStatsOut",
    "RecommendationBody",
    "FleetRecommendationOut",
    "FleetHistoryEntryOut",
    "FleetHistoryOut",
    "SolveRequestOut",
    "rows_out",
]


class _Out(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SizeRowOut(_Out):
    """One candidate fleet size of a KPI's table."""

    size: int = Field(description="Instrumented fleet size N1.")
    n_samples: int = Field(description="M, the KPI samples (days) behind the row.")
    mean: float = Field(description="Sample mean of the KPI.")
    worst_case: float = Field(description="Worst-case expectation over the divergence ball.")
    premium: float = Field(description="worst_case - mean.")
    rho: float = Field(description="Radius of the ball.")
    m: int = Field(description="Cells of the empirical distribution.")
    status: str = Field(description="The worst-case solve's status: optimal, saturated or degenerate.")

    @classmethod
    def of(cls, row: SizeRow) -> SizeRowOut:
        """From the core's row."""
        return cls(
            size=row.size,
            n_samples=row.n_samples,
            mean=row.mean,
            worst_case=row.worst_case,
            premium=row.premium,
            rho=row.rho,
            m=row.m,
            status=row.status,
        )


def rows_out(table: SizeTable) -> list[SizeRowOut]:
    """A table's rows, ascending size."""
    return [SizeRowOut.of(r) for r in table.rows]


class ChoiceOut(_Out):
    """A method's chosen size: its objective (sample mean or worst case) and the sizes tied with it."""

    size: int
    objective: float
    tied: list[int] = Field(description="Sizes whose objective ties the optimum; the smallest is chosen.")
    status: Literal["unique", "tie"]

    @classmethod
    def of(cls, choice: Choice) -> ChoiceOut:
        """From the core's choice."""
        return cls(size=choice.size, objective=choice.objective, tied=list(choice.tied), status=choice.status)


class HourChoiceOut(ChoiceOut):
    """DRO_RH's choice for one hour of the horizon."""

    interval: str = Field(description="Local start of the hour, YYYY-MM-DDTHH:MM.")
    position: int = Field(description="Hour of the horizon, 0-based.")


class ChosenOut(_Out):
    """The chosen size per method."""

    deterministic: int = Field(description="Argmin of the sample mean of the daily design KPI.")
    dro: int = Field(description="Argmin of the worst-case daily design KPI (one size for the day).")
    dro_rh: int = Field(description="Argmin of the worst-case design KPI of the coming hour.")
    completion_target: int | None = Field(
        description="Smallest size whose worst-case POI completion rate meets the target (null: none does, "
        "or the target is off)."
    )


class CompletionTargetOut(_Out):
    """The completion-rate target: the smallest size meeting it on the worst case, and the table."""

    target: float
    size: int | None
    status: Literal["met", "unmet"]
    best_size: int = Field(description="The size with the highest worst-case completion rate.")
    best_worst_case: float
    table: list[SizeRowOut] = Field(description="Completion rate per size; worst_case is the infimum.")

    @classmethod
    def of(cls, goal: TargetChoice) -> CompletionTargetOut:
        """From the core's target choice."""
        return cls(
            target=goal.target,
            size=goal.size,
            status=goal.status,
            best_size=goal.best_size,
            best_worst_case=goal.best_worst_case,
            table=rows_out(goal.table),
        )


class DataWindowOut(_Out):
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


class SimulationOut(_Out):
    """How each (size, day) run was simulated."""

    n0: int = Field(description="Ordinary taxis.")
    n_tasks: int = Field(description="POI monitoring tasks.")
    rate_per_hour: float | None = Field(description="Synthetic requests per hour (null: city default).")
    seed: int


class SolveStatsOut(_Out):
    """What the solve cost."""

    runs: int
    cached_runs: int
    wall_s: float
    jobs: int


class RecommendationBody(_Out):
    """A fleet-sizing recommendation as the worker publishes it."""

    city: str
    interval: str = Field(description="The hour solved for (local start, YYYY-MM-DDTHH:MM).")
    interval_start: str = Field(description="Its start, RFC 3339 in the city's time zone.")
    position: int = Field(description="Hour of the horizon, 0-based.")
    trigger: Literal["schedule", "request"]
    request_id: str | None
    kpi: str = Field(description="What the tables measure.")
    chosen: ChosenOut
    deterministic: ChoiceOut
    dro: ChoiceOut
    dro_rh: HourChoiceOut
    dro_rh_by_hour: list[HourChoiceOut] = Field(description="DRO_RH for every hour of the horizon.")
    hour_table: list[SizeRowOut] = Field(description="Design KPI of the coming hour per size (DRO_RH's).")
    daily_table: list[SizeRowOut] = Field(description="Daily design KPI per size (Deterministic's, DRO's).")
    completion_target: CompletionTargetOut | None
    divergence: str
    alpha: float
    support: Literal["binned", "samples"]
    bins: int
    sizes: list[int]
    data_window: DataWindowOut
    simulation: SimulationOut
    solve: SolveStatsOut


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


class FleetHistoryEntryOut(_Out):
    """One solve: published (with its recommendation) or failed (with the reason)."""

    status: Literal["published", "failed"]
    computed_at: str
    interval: str
    version: int | None
    reason: str | None
    request_id: str | None
    recommendation: FleetRecommendationOut | None


class FleetHistoryOut(_Out):
    """Solves of a city, newest first."""

    city: str
    entries: list[FleetHistoryEntryOut]


class SolveRequestOut(_Out):
    """A queued solve request (the worker picks it up within its poll interval)."""

    request_id: str = Field(description="Shows up as request_id in the history once solved.")
    city: str
    status: Literal["queued", "already_queued"] = Field(
        description="already_queued: a request was pending; this one joins it (same request_id)."
    )
    requested_at: str
