"""Distributionally robust fleet sizing: Deterministic, DRO and DRO_RH (METHOD section 8, paper Section 3.3).

Input: for every candidate fleet size ``x`` (instrumented taxis, ``N1``) an array of ``M`` KPI samples,
``samples[x][j]`` the KPI of the run with fleet ``x`` on demand sample ``j`` -- the daily design KPI for
Deterministic and DRO, the hour-``h`` design KPI for DRO_RH (one mapping per hour). Nothing is simulated
here; :mod:`app.worker` and the experiment produce the samples.

* **Deterministic**: ``argmin_x`` of the sample mean.
* **DRO** (predetermined, Eq. (18)): ``argmin_x`` of the worst-case expectation over the φ-divergence ball
  around the empirical distribution of ``samples[x]``; one size for the whole horizon.
* **DRO_RH** (rolling horizon): per hour ``h``, ``argmin_x`` of the worst case of that hour's samples.
* **Beyond the paper**: :func:`cheapest_meeting_target`, the smallest fleet whose worst-case expected POI
  completion rate still meets a target. Completion is a "higher is better" KPI, so its worst case is the
  *infimum* over the ball, ``inf E_p[f] = -sup E_p[-f]``.

Ties (values equal within a relative ``1e-9``) are broken toward the **smaller** fleet: fewer instrumented
vehicles cost less to equip and subsidize, and a KPI that cannot tell two sizes apart gives no reason to pay
for the larger one. Every result reports the tied sizes and says ``status="tie"`` when it happened.

The worst-case expectation is the DRO engine's (:func:`services.dro.worst_case`): support, radius
``ρ = φ''(1) / (2M) · χ²_{m-1, 1-α}`` and the exact solve follow the :class:`Ambiguity` passed in.

:func:`realized_fixed` and :func:`realized_rolling` evaluate a choice on held-out test days (the last column
of the paper's Table 2).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from services.dro import SUPPORT_KINDS, DroInputError, SupportKind, get_divergence, worst_case
from services.dro.inputs import check_alpha

__all__ = [
    "TIE_RTOL",
    "FleetInputError",
    "Sense",
    "FleetMethod",
    "ChoiceStatus",
    "TargetStatus",
    "Ambiguity",
    "SizeRow",
    "SizeTable",
    "Choice",
    "RollingChoice",
    "TargetChoice",
    "FleetPlan",
    "Realized",
    "size_table",
    "deterministic",
    "dro",
    "dro_rh",
    "cheapest_meeting_target",
    "plan_fleet",
    "realized_fixed",
    "realized_rolling",
]

FloatArray = NDArray[np.float64]
Sense = Literal["min", "max"]
"""``"min"``: lower is better (cost, the design KPI); ``"max"``: higher is better (completion rate)."""
FleetMethod = Literal["deterministic", "dro", "dro_rh"]
ChoiceStatus = Literal["unique", "tie"]
"""``unique``: one size attains the optimum; ``tie``: several do (within ``TIE_RTOL``), the smallest won."""
TargetStatus = Literal["met", "unmet"]
"""``met``: some size meets the target (the smallest such is chosen); ``unmet``: none does."""

TIE_RTOL = 1e-9


class FleetInputError(ValueError):
    """Bad input to fleet sizing; ``parameter`` names it (``"samples"``, ``"target"``, ...)."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(f"{parameter}: {message}")
        self.parameter = parameter
        self.message = message


@dataclass(frozen=True, slots=True)
class Ambiguity:
    """The ambiguity set: φ-divergence, significance level α and the support of the empirical distribution.

    Defaults are METHOD section 8's: Kullback-Leibler, α = 0.05, ``w = 10`` equal-width bins.
    """

    divergence: str = "kl"
    alpha: float = 0.05
    support: SupportKind = "binned"
    bins: int = 10

    def __post_init__(self) -> None:
        try:
            get_divergence(self.divergence)
        except ValueError as exc:
            raise FleetInputError("divergence", str(exc)) from None
        try:
            check_alpha(self.alpha)
        except DroInputError as exc:
            raise FleetInputError("alpha", exc.message) from None
        if self.support not in SUPPORT_KINDS:
            raise FleetInputError(
                "support", f"must be one of {', '.join(SUPPORT_KINDS)}, got {self.support!r}"
            )
        if isinstance(self.bins, bool) or not isinstance(self.bins, int) or self.bins < 2:
            raise FleetInputError("bins", f"must be an integer >= 2, got {self.bins!r}")


@dataclass(frozen=True, slots=True)
class SizeRow:
    """One candidate size: sample mean, worst-case expectation, their difference, the radius and cells.

    ``premium = worst_case - mean``: what robustness adds (positive for ``sense="min"``; for ``"max"`` the
    worst case is the infimum and the premium is negative or zero). ``status`` is the engine's
    (``optimal``, ``saturated`` or ``degenerate``).
    """

    size: int
    n_samples: int
    mean: float
    worst_case: float
    premium: float
    rho: float
    m: int
    status: str


@dataclass(frozen=True, slots=True)
class SizeTable:
    """The per-size rows of one KPI (ascending size), the ambiguity set and the KPI's sense."""

    rows: tuple[SizeRow, ...]
    ambiguity: Ambiguity
    sense: Sense

    @property
    def sizes(self) -> tuple[int, ...]:
        """The candidate sizes, ascending."""
        return tuple(r.size for r in self.rows)

    def row(self, size: int) -> SizeRow:
        """The row of ``size`` (``KeyError`` if it is not a candidate)."""
        for r in self.rows:
            if r.size == size:
                return r
        raise KeyError(size)


@dataclass(frozen=True, slots=True)
class Choice:
    """A chosen size: the method, the size, its objective (sample mean or worst case), the tied sizes."""

    method: FleetMethod
    size: int
    objective: float
    tied: tuple[int, ...]  # every size within TIE_RTOL of the optimum, ascending; ``size`` is the first
    status: ChoiceStatus


@dataclass(frozen=True, slots=True)
class RollingChoice:
    """DRO_RH: one choice and one table per hour of the horizon."""

    choices: tuple[Choice, ...]
    tables: tuple[SizeTable, ...]

    @property
    def sizes(self) -> tuple[int, ...]:
        """The chosen size of every hour."""
        return tuple(c.size for c in self.choices)

    @property
    def status(self) -> ChoiceStatus:
        """``tie`` when any hour's choice was a tie."""
        return "tie" if any(c.status == "tie" for c in self.choices) else "unique"


@dataclass(frozen=True, slots=True)
class TargetChoice:
    """The smallest size whose worst-case expected KPI (sense ``max``) meets ``target``, or none.

    ``best_size`` is the size with the highest worst case (ties: the smaller), reported either way so an
    unmet target says how far off the best fleet is.
    """

    target: float
    size: int | None
    status: TargetStatus
    best_size: int
    best_worst_case: float
    table: SizeTable


@dataclass(frozen=True, slots=True)
class FleetPlan:
    """Everything one solve decides: the daily table with Deterministic and DRO, DRO_RH per hour and,
    when asked for, the completion-target choice."""

    daily: SizeTable
    deterministic: Choice
    dro: Choice
    rolling: RollingChoice
    completion: TargetChoice | None


@dataclass(frozen=True, slots=True)
class Realized:
    """A choice's design KPI on test days: the mean over days and each day's value."""

    value: float
    per_day: tuple[float, ...]
    sizes: tuple[int, ...]  # the size of every hour (one entry for a fixed size)


# ---------------------------------------------------------------------------------------------- inputs


def _check_size(size: object, parameter: str = "samples") -> int:
    if isinstance(size, bool) or not isinstance(size, int | np.integer) or int(size) < 1:
        raise FleetInputError(parameter, f"fleet sizes must be positive integers, got {size!r}")
    return int(size)


def _as_samples(size: int, values: ArrayLike, minimum: int) -> FloatArray:
    try:
        x = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FleetInputError("samples", f"size {size}: not numbers ({exc})") from None
    if x.ndim != 1 or x.size < minimum:
        raise FleetInputError(
            "samples", f"size {size}: need a 1-D array of at least {minimum} values, got shape {x.shape}"
        )
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise FleetInputError("samples", f"size {size}: sample {int(bad[0])} is {x[bad[0]]}, not finite")
    return x


def _sorted_samples(samples: Mapping[int, ArrayLike], minimum: int) -> list[tuple[int, FloatArray]]:
    if not samples:
        raise FleetInputError("samples", "no candidate sizes")
    out = [(_check_size(x), _as_samples(int(x), v, minimum)) for x, v in samples.items()]
    out.sort(key=lambda item: item[0])
    return out


# ------------------------------------------------------------------------------------------------ core


def size_table(
    samples: Mapping[int, ArrayLike], ambiguity: Ambiguity | None = None, *, sense: Sense = "min"
) -> SizeTable:
    """Mean, worst-case expectation, premium, ρ and m of every candidate size.

    Parameters
    ----------
    samples
        ``samples[x]``: the ``M >= 2`` KPI samples of size ``x`` (finite).
    ambiguity
        Divergence, α and support (default :class:`Ambiguity`).
    sense
        ``"min"``: the worst case is the supremum over the ball (Eq. (18)); ``"max"``: the infimum,
        ``-sup E_p[-f]``.

    Raises
    ------
    FleetInputError
        Naming the parameter: no sizes, a size below 1, fewer than two samples, a non-finite sample.
    """
    amb = ambiguity or Ambiguity()
    if sense not in ("min", "max"):
        raise FleetInputError("sense", f"must be 'min' or 'max', got {sense!r}")
    sign = 1.0 if sense == "min" else -1.0
    rows = []
    for x, f in _sorted_samples(samples, 2):
        try:
            wc = worst_case(sign * f, amb.divergence, alpha=amb.alpha, support=amb.support, bins=amb.bins)
        except DroInputError as exc:
            raise FleetInputError(exc.parameter, f"size {x}: {exc.message}") from None
        value, mean = sign * float(wc.value), float(np.mean(f))
        rows.append(
            SizeRow(
                size=x,
                n_samples=int(f.size),
                mean=mean,
                worst_case=value,
                premium=value - mean,
                rho=float(wc.rho),
                m=int(wc.m),
                status=str(wc.status),
            )
        )
    return SizeTable(tuple(rows), amb, sense)


def _tied(values: Sequence[float]) -> list[int]:
    """Indices of the values within ``TIE_RTOL`` of the minimum."""
    best = min(values)
    return [i for i, v in enumerate(values) if v == best or math.isclose(v, best, rel_tol=TIE_RTOL)]


def _choose(table: SizeTable, method: FleetMethod, key: str) -> Choice:
    sign = 1.0 if table.sense == "min" else -1.0
    values = [sign * float(getattr(r, key)) for r in table.rows]
    tied = _tied(values)
    first = table.rows[tied[0]]
    return Choice(
        method=method,
        size=first.size,
        objective=float(getattr(first, key)),
        tied=tuple(table.rows[i].size for i in tied),
        status="tie" if len(tied) > 1 else "unique",
    )


def deterministic(table: SizeTable) -> Choice:
    """The size with the best sample mean (ties: the smallest)."""
    return _choose(table, "deterministic", "mean")


def dro(table: SizeTable) -> Choice:
    """The size with the best worst-case expectation (ties: the smallest)."""
    return _choose(table, "dro", "worst_case")


def dro_rh(tables: Sequence[SizeTable]) -> RollingChoice:
    """DRO_RH: per hour, the size with the best worst case of that hour's samples (ties: the smallest)."""
    if not tables:
        raise FleetInputError("samples", "no hours")
    choices = tuple(Choice("dro_rh", c.size, c.objective, c.tied, c.status) for c in (dro(t) for t in tables))
    return RollingChoice(choices, tuple(tables))


def cheapest_meeting_target(
    samples: Mapping[int, ArrayLike], target: float, ambiguity: Ambiguity | None = None
) -> TargetChoice:
    """The smallest size whose worst-case expected value (the infimum over the ball) is at least ``target``.

    Meant for the POI completion rate: a fleet whose completion could fall below the target under a
    plausible demand distribution is not recommended, however cheap it is. ``status="unmet"`` and
    ``size=None`` when no candidate meets the target.
    """
    t = float(target)
    if not math.isfinite(t):
        raise FleetInputError("target", f"must be finite, got {target!r}")
    table = size_table(samples, ambiguity, sense="max")
    meets = [r for r in table.rows if r.worst_case >= t]
    best = _choose(table, "dro", "worst_case")
    return TargetChoice(
        target=t,
        size=meets[0].size if meets else None,
        status="met" if meets else "unmet",
        best_size=best.size,
        best_worst_case=best.objective,
        table=table,
    )


def plan_fleet(
    daily: Mapping[int, ArrayLike],
    hourly: Sequence[Mapping[int, ArrayLike]],
    ambiguity: Ambiguity | None = None,
    *,
    completion: Mapping[int, ArrayLike] | None = None,
    target: float | None = None,
) -> FleetPlan:
    """One solve: Deterministic and DRO on the daily KPI, DRO_RH on every hour's KPI, and the completion
    target when both ``completion`` samples and ``target`` are given."""
    amb = ambiguity or Ambiguity()
    table = size_table(daily, amb)
    rolling = dro_rh([size_table(h, amb) for h in hourly])
    if (completion is None) != (target is None):
        raise FleetInputError("target", "give both completion samples and a target, or neither")
    goal = None
    if completion is not None and target is not None:
        goal = cheapest_meeting_target(completion, target, amb)
    return FleetPlan(table, deterministic(table), dro(table), rolling, goal)


# ------------------------------------------------------------------------------------- test-day KPIs


def realized_fixed(test_daily: Mapping[int, ArrayLike], size: int) -> Realized:
    """The design KPI of a fixed size on test days: the mean over days of the daily KPI of the run with
    that size (``test_daily[x][d]``)."""
    x = _check_size(size, "size")
    if x not in test_daily:
        raise FleetInputError("size", f"no test runs for size {x}")
    f = _as_samples(x, test_daily[x], 1)
    return Realized(float(np.mean(f)), tuple(float(v) for v in f), (x,))


def realized_rolling(
    test_hour_cost: Mapping[int, ArrayLike],
    sizes_by_hour: Sequence[int],
    *,
    interval_hours: float = 1.0,
    subsidy_cny_per_vehicle_hour: float = 0.0,
) -> Realized:
    """The design KPI of hour-by-hour sizes ``x_h`` on test days (METHOD section 7 summed over hours):

    ``KPI_d = (Σ_h cost_{d,h}(x_h) + ζ Σ_h x_h τ) / (Σ_h x_h τ)``, averaged over the test days ``d``,

    ``cost_{d,h}(x) = test_hour_cost[x][d, h]`` the hour-``h`` monitoring cost of day ``d``'s run with fleet
    ``x``, ``τ`` the interval length in hours and ζ the subsidy.

    Notes
    -----
    An approximation: every run was simulated with one fleet size all day, so ``cost_h(x_h)`` is the cost
    of hour ``h`` *in a day run entirely with* ``x_h``. A fleet that really changes size at the hour starts
    the hour with the previous hour's taxi positions and Lambda counts, which the runs do not reproduce.
    With ``x_h = x`` for every hour it is exactly the daily design KPI of the run with ``x``.
    """
    hours = [_check_size(x, "sizes_by_hour") for x in sizes_by_hour]
    if not hours:
        raise FleetInputError("sizes_by_hour", "no hours")
    tau = float(interval_hours)
    if not (math.isfinite(tau) and tau > 0):
        raise FleetInputError("interval_hours", f"must be positive, got {interval_hours!r}")
    costs: dict[int, FloatArray] = {}
    for x in sorted(set(hours)):
        if x not in test_hour_cost:
            raise FleetInputError("sizes_by_hour", f"no test runs for size {x}")
        c = np.asarray(test_hour_cost[x], dtype=np.float64)
        if c.ndim != 2 or c.shape[0] < 1 or c.shape[1] != len(hours) or not np.all(np.isfinite(c)):
            raise FleetInputError(
                "test_hour_cost",
                f"size {x}: need a finite (days, {len(hours)}) array, got shape {c.shape}",
            )
        costs[x] = c
    n_days = {c.shape[0] for c in costs.values()}
    if len(n_days) != 1:
        raise FleetInputError(
            "test_hour_cost", f"sizes have different numbers of test days: {sorted(n_days)}"
        )
    vehicle_hours = tau * float(sum(hours))
    total = sum(costs[x][:, h] for h, x in enumerate(hours))
    per_day = (np.asarray(total) + subsidy_cny_per_vehicle_hour * vehicle_hours) / vehicle_hours
    return Realized(float(np.mean(per_day)), tuple(float(v) for v in per_day), tuple(hours))
