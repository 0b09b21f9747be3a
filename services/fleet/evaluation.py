"""Realized cost of fleet-sizing decisions on held-out test days (docs/METHOD.md section 8, the last column of
the paper's Table 2).

A method is judged by what its chosen sizes *cost* on days it has not seen -- the platform's total cost per
hour, Step 3 cost plus ζ per instrumented vehicle-hour -- never by the bound it certified: the mean of hourly
worst cases is never below the daily worst case by construction, so comparing certificates says nothing
about which method is better.

* :func:`realized_fixed`: one size all day (Deterministic, DRO).
* :func:`rolling_decisions`: DRO_RH on a test day -- before every hour it conditions on the hours of *that*
  day already past and decides (:func:`services.fleet.sizing.rolling_hour`).
* :func:`realized_by_hour`: the cost of hour-by-hour sizes.

Approximation: each run keeps one fleet size all day, so the cost of hour ``h`` at size ``x_h`` is taken from
the test day's run with ``x_h`` taxis all day. A fleet that really changes size at the hour starts it with
the previous hour's taxi positions and Λ counts, which the runs do not reproduce.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from services.fleet.sizing import (
    Ambiguity,
    CostModel,
    DayOutcomes,
    FleetInputError,
    RollingHour,
    rolling_hour,
)

__all__ = ["Realized", "realized_fixed", "realized_by_hour", "rolling_decisions"]


@dataclass(frozen=True, slots=True)
class Realized:
    """Realized total cost per hour (CNY) on the test days: the mean over days, each day's value, each
    day-hour's value and the sizes used (``sizes[d][h]``)."""

    value: float
    per_day: tuple[float, ...]
    per_hour: tuple[tuple[float, ...], ...]
    sizes: tuple[tuple[int, ...], ...]


def _test_cost(test: Mapping[int, DayOutcomes], size: int) -> DayOutcomes:
    if size not in test:
        raise FleetInputError("size", f"no test runs for size {size}")
    return test[size]


def realized_by_hour(
    test: Mapping[int, DayOutcomes], sizes: Sequence[Sequence[int]], costs: CostModel | None = None
) -> Realized:
    """The total cost per hour of sizes ``sizes[d][h]`` on test day ``d``, hour ``h``:
    ``cost_{d,h}(x_{d,h}) / τ + ζ x_{d,h}``, averaged over hours (per day) and over days."""
    cm = costs or CostModel()
    if not sizes:
        raise FleetInputError("sizes", "no test days")
    n_days = {o.n_days for o in test.values()}
    if len(n_days) != 1 or len(sizes) != n_days.pop():
        raise FleetInputError("sizes", "need one row of sizes per test day, and equal test days per size")
    per_hour: list[tuple[float, ...]] = []
    for d, row in enumerate(sizes):
        values = []
        for h, x in enumerate(row):
            o = _test_cost(test, int(x))
            if len(row) != o.n_hours:
                raise FleetInputError("sizes", f"day {d}: need {o.n_hours} hourly sizes, got {len(row)}")
            values.append(
                float(o.cost_cny[d, h]) / cm.interval_hours + cm.subsidy_cny_per_vehicle_hour * int(x)
            )
        per_hour.append(tuple(values))
    per_day = tuple(float(np.mean(v)) for v in per_hour)
    return Realized(
        float(np.mean(per_day)), per_day, tuple(per_hour), tuple(tuple(int(x) for x in r) for r in sizes)
    )


def realized_fixed(test: Mapping[int, DayOutcomes], size: int, costs: CostModel | None = None) -> Realized:
    """The total cost per hour of one size all day on every test day."""
    o = _test_cost(test, int(size))
    return realized_by_hour(test, [[int(size)] * o.n_hours] * o.n_days, costs)


def rolling_decisions(
    train: Mapping[int, DayOutcomes],
    train_volumes: ArrayLike,
    day_volumes: ArrayLike,
    *,
    keep: int,
    ambiguity: Ambiguity | None = None,
    costs: CostModel | None = None,
    target: float | None = None,
) -> tuple[RollingHour, ...]:
    """DRO_RH as it unfolds on one day: the decision for every hour ``h``, made before it with the day's
    volumes of hours ``0..h-1`` observed (``day_volumes``: the day's requests per interval)."""
    obs = np.asarray(day_volumes, dtype=np.float64).reshape(-1)
    n_hours = next(iter(train.values())).n_hours if train else 0
    if obs.size != n_hours:
        raise FleetInputError("day_volumes", f"need {n_hours} volumes, got {obs.size}")
    return tuple(
        rolling_hour(
            train, train_volumes, obs[:h], h, keep=keep, ambiguity=ambiguity, costs=costs, target=target
        )
        for h in range(n_hours)
    )
