"""KPIs of a simulated horizon (docs/METHOD.md sections 6, 7 and 10), per run and per hour.

Riders: matching rate (matched / posted requests), wait from request to pickup (time waiting to be matched
plus the pickup drive), riders lost (patience ran out) and unserved (lost, or still waiting at the end).
Sensing: Gamma (Eq. 1) and the grid coverage rate (mean over the horizon's intervals of the share of the
cells the network touches that were crossed at least once). Tasks: completion rate (reached by the end of the
horizon / all tasks) and timeliness (completion - scheduled time, per task). Cost: 1.5 CNY/km of Step 3 routes
plus the subsidy; the design KPI is that per instrumented vehicle-hour (docs/METHOD.md section 7).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.model import Task
from services.sensing.sensing import coverage_rate, gamma
from services.sim.engine import RunTrace

__all__ = [
    "HourKpis",
    "TaskOutcome",
    "RunKpis",
    "run_kpis",
    "design_kpi",
    "price_of_sensing",
    "reachable_tasks_by_interval",
]


@dataclass(frozen=True, slots=True)
class HourKpis:
    """One sensing interval (an hour by default) of a run."""

    interval: int  # position in the horizon, 0-based
    requests: int
    matched: int
    matching_rate: float
    avg_wait_s: float
    coverage_rate: float
    gamma: float  # mu_t * sum_g s_g Theta(Lambda_{g,t})
    monitoring_cost_cny: float
    design_kpi: float  # cost per instrumented vehicle-hour in this hour (NaN without instrumented taxis)
    tasks_completed: int


@dataclass(frozen=True, slots=True)
class TaskOutcome:
    task_id: str
    node: int
    scheduled_at_s: float
    completed_at_s: float | None  # None: not reached within the horizon
    delay_s: float | None
    mode: str | None  # "passive" / "active"
    taxi_id: str | None


@dataclass(frozen=True, slots=True)
class RunKpis:
    n_requests: int
    n_matched: int
    n_step1: int
    n_step2: int
    matching_rate: float
    avg_wait_s: float
    avg_pickup_s: float
    total_wait_s: float
    riders_lost: int
    riders_unserved: int
    gamma: float
    coverage_rate: float
    n_tasks: int
    n_completed: int
    n_active: int
    n_passive: int
    completion_rate: float
    mean_delay_s: float
    route_km: float
    monitoring_cost_cny: float
    design_kpi: float
    solve_ms_median: float
    hours: tuple[HourKpis, ...]
    tasks: tuple[TaskOutcome, ...]

    def scalars(self) -> dict[str, Any]:
        """The per-run numbers (no per-hour or per-task lists), for a results table."""
        d = asdict(self)
        d.pop("hours")
        d.pop("tasks")
        return d


def design_kpi(
    cost_cny: float, n_instrumented: int, hours: float, subsidy_cny_per_vehicle_hour: float
) -> float:
    """KPI(x, Q) = (cost + zeta * x * hours) / (x * hours) (docs/METHOD.md section 7); NaN when x * hours
    is 0."""
    if n_instrumented <= 0 or hours <= 0:
        return float("nan")
    return (cost_cny + subsidy_cny_per_vehicle_hour * n_instrumented * hours) / (n_instrumented * hours)


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def _task_outcome(t: Task, end_s: float) -> TaskOutcome:
    """What became of a task by the end of the run (``end_s``)."""
    at = t.completed_at_s
    done = t.status in ("assigned", "completed") and at is not None and at <= end_s
    return TaskOutcome(
        task_id=str(t.id),
        node=t.node,
        scheduled_at_s=t.scheduled_at_s,
        completed_at_s=at if done else None,
        delay_s=at - t.scheduled_at_s if done and at is not None else None,
        mode=t.mode if done else None,
        taxi_id=str(t.taxi_id) if done and t.taxi_id is not None else None,
    )


def run_kpis(city: City, trace: RunTrace) -> RunKpis:
    """The KPIs of one simulated horizon."""
    hz, p = city.horizon, city.params
    x = trace.config.n_instrumented
    zeta = p.subsidy_cny_per_vehicle_hour
    hour_s = float(hz.interval_s)
    n_int = hz.n_intervals

    def pos(t: float) -> int:
        return min(max(int((t - trace.start_s) // hour_s), 0), n_int - 1)

    riders = trace.riders
    matched = [r for r in riders if r.matched_at_s is not None]
    waits = [float(r.wait_s) for r in matched if r.wait_s is not None]
    lost = sum(1 for r in riders if r.left_at_s is not None)

    outcomes = [_task_outcome(t, trace.end_s) for t in trace.tasks]
    completed = [o for o in outcomes if o.completed_at_s is not None]

    day = sorted(trace.counts)
    hours: list[HourKpis] = []
    for i in range(n_int):
        k = day[i] if i < len(day) else None
        arr = trace.counts.get(k) if k is not None else None
        in_hour = [r for r in riders if pos(r.requested_at_s) == i]
        hit = [r for r in in_hour if r.matched_at_s is not None]
        cost = sum(a.cost_cny for t, a in trace.assignments if pos(t) == i)
        hours.append(
            HourKpis(
                interval=i,
                requests=len(in_hour),
                matched=len(hit),
                matching_rate=len(hit) / len(in_hour) if in_hour else float("nan"),
                avg_wait_s=_mean([float(r.wait_s) for r in hit if r.wait_s is not None]),
                coverage_rate=coverage_rate(city, arr) if arr is not None else 0.0,
                gamma=gamma(city, {k: arr}, [k]) if arr is not None and k is not None else 0.0,
                monitoring_cost_cny=cost,
                design_kpi=design_kpi(cost, x, 1.0 * hour_s / 3600.0, zeta),
                tasks_completed=sum(
                    1 for o in completed if o.completed_at_s is not None and pos(o.completed_at_s) == i
                ),
            )
        )
    route_m = sum(a.length_m for _, a in trace.assignments)
    cost = sum(a.cost_cny for _, a in trace.assignments)
    n = len(riders)
    return RunKpis(
        n_requests=n,
        n_matched=len(matched),
        n_step1=sum(1 for r in matched if r.step == 1),
        n_step2=sum(1 for r in matched if r.step == 2),
        matching_rate=len(matched) / n if n else float("nan"),
        avg_wait_s=_mean(waits),
        avg_pickup_s=_mean([float(r.pickup_s) for r in matched if r.pickup_s is not None]),
        total_wait_s=float(sum(waits)),
        riders_lost=lost,
        riders_unserved=n - len(matched),
        gamma=gamma(city, trace.counts, day),
        coverage_rate=float(np.mean([h.coverage_rate for h in hours])) if hours else 0.0,
        n_tasks=len(outcomes),
        n_completed=len(completed),
        n_active=sum(1 for o in completed if o.mode == "active"),
        n_passive=sum(1 for o in completed if o.mode == "passive"),
        completion_rate=len(completed) / len(outcomes) if outcomes else float("nan"),
        mean_delay_s=_mean([o.delay_s for o in completed if o.delay_s is not None]),
        route_km=route_m / 1000.0,
        monitoring_cost_cny=cost,
        design_kpi=design_kpi(cost, x, hz.length_s / 3600.0, zeta),
        solve_ms_median=float(np.median([e.solve_ms for e in trace.epochs]))
        if trace.epochs
        else float("nan"),
        hours=tuple(hours),
        tasks=tuple(outcomes),
    )


def price_of_sensing(run: Mapping[str, Any], baseline: Mapping[str, Any]) -> dict[str, float | None]:
    """What sensing cost the riders, against the same demand and seed matched on wait alone.

    ``run`` and ``baseline`` are ``RunKpis.scalars()`` (or the same numbers read back from JSON, where a
    NaN average is ``None``). ``extra_wait_s``: total request-to-pickup wait of the run minus the
    baseline's; ``extra_avg_wait_s``: difference of the average waits (``None`` when either run matched
    nobody); ``extra_riders_lost``: riders left unserved minus the baseline's; ``matching_rate_drop``.
    """

    def diff(key: str, a: Mapping[str, Any], b: Mapping[str, Any]) -> float | None:
        x, y = a.get(key), b.get(key)
        if x is None or y is None or not (math.isfinite(x) and math.isfinite(y)):
            return None
        return float(x) - float(y)

    return {
        "extra_wait_s": diff("total_wait_s", run, baseline),
        "extra_avg_wait_s": diff("avg_wait_s", run, baseline),
        "extra_riders_lost": diff("riders_unserved", run, baseline),
        "matching_rate_drop": diff("matching_rate", baseline, run),
    }


def reachable_tasks_by_interval(
    tasks: Sequence[TaskOutcome], start_s: float, interval_s: float, n_intervals: int, reach_s: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per interval of the horizon, the tasks scheduled in it that can still be reached within the horizon
    and how many of them were completed within it (docs/METHOD.md section 8).

    A task scheduled less than ``reach_s`` before the end of the horizon is not counted: a taxi sent at its
    scheduled time could not be expected to arrive before the horizon closes, so missing it says nothing
    about the fleet's size.
    """
    if interval_s <= 0 or n_intervals < 1 or reach_s < 0:
        raise ValueError("interval_s and n_intervals must be positive and reach_s non-negative")
    end_s = start_s + interval_s * n_intervals
    due = np.zeros(n_intervals, dtype=np.int64)
    done = np.zeros(n_intervals, dtype=np.int64)
    for t in tasks:
        if not start_s <= t.scheduled_at_s <= end_s - reach_s or t.scheduled_at_s >= end_s:
            continue
        i = min(int((t.scheduled_at_s - start_s) // interval_s), n_intervals - 1)
        due[i] += 1
        done[i] += t.completed_at_s is not None
    return due, done
