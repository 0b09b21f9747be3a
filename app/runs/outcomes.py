"""From finished runs to the fleet-sizing inputs (``services.fleet.sizing.DayOutcomes`` and hourly request
volumes), one function for the worker and the experiment alike."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from app.runs.result import RunResult
from services.city import Horizon
from services.fleet.sizing import DayOutcomes
from services.sim.kpi import reachable_tasks_by_interval

__all__ = ["day_outcomes", "hourly_volumes"]


def day_outcomes(runs: Sequence[RunResult], horizon: Horizon, reach_s: float) -> DayOutcomes:
    """One size's runs on ``M`` days (in day order): Step 3 cost per interval, and the reachable tasks due
    and completed per interval (tasks scheduled at least ``reach_s`` before the horizon ends)."""
    cost, due, done = [], [], []
    for r in runs:
        cost.append([h.monitoring_cost_cny for h in r.kpis.hours])
        d, c = reachable_tasks_by_interval(
            r.kpis.tasks, horizon.start_s(r.date), float(horizon.interval_s), horizon.n_intervals, reach_s
        )
        due.append(d)
        done.append(c)
    return DayOutcomes.of(cost, due, done)


def hourly_volumes(runs: Sequence[RunResult]) -> NDArray[np.float64]:
    """Requests per interval of every run's day (``(M, H)``), as the platform posted them."""
    return np.asarray([[h.requests for h in r.kpis.hours] for r in runs], dtype=np.float64)
