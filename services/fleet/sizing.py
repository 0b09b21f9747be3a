"""Distributionally robust fleet sizing: Deterministic, DRO and DRO_RH (docs/METHOD.md sections 7-8, paper
Section 3.3).

Input: for every candidate fleet size ``x`` (instrumented taxis, ``N1``) what its simulations gave on ``M``
demand days -- per day and hour the Step 3 monitoring cost and the reachable POI tasks due and completed
(:class:`DayOutcomes`) -- and the request volume of every day and hour. Nothing is simulated here;
:mod:`app.worker` and the experiment produce the outcomes.

**The objective is the platform's total cost per hour** (Eq. (17) with the Eq. (29) subsidy term)::

    KPI_total(x, Q) = 1.5 CNY/km x Step 3 km per hour + ζ x

with ζ the subsidy per instrumented vehicle-hour (:class:`CostModel`). The per-vehicle design KPI the paper's
Table 2 prints, ``KPI_total / x``, is reported beside it but never sized on: its ``1/x`` divisor alone makes
the largest candidate win.

* **Deterministic**: ``argmin_x`` of the sample mean of the daily total cost per hour.
* **DRO** (predetermined, Eq. (18)): ``argmin_x`` of its worst-case expectation over the φ-divergence ball;
  one size for the whole horizon.
* **DRO_RH** (rolling horizon): before hour ``h`` of day ``d``, the history is conditioned on what day ``d``
  has shown so far (:func:`similar_days`: the ``keep`` days whose request volumes in the hours already past
  are closest to day ``d``'s), and ``x_h = argmin_x`` of the worst case of hour ``h``'s total cost on those
  days. A later hour's choice therefore changes as the day unfolds.
* **Optional completion target**: only sizes whose completion rate on the reachable tasks (worst case, the
  infimum over the ball, for DRO and DRO_RH; the mean for Deterministic) meets the target are eligible.
  When none does the method takes the size with the best completion and says ``target_met=False``.

Ties (values equal within a relative ``1e-9``) are broken toward the **smaller** fleet and reported
(``status="tie"``). The worst-case expectation is :func:`services.fleet.dro.worst_case` with the
:class:`Ambiguity` given; every table row carries the paper's box LP (Eq. (28)) beside the exact value.

Because ζ x is a constant for a given ``x``, the worst case of the total is the worst case of the Step 3
cost plus ζ x for every divergence (the ball is over distributions, and a constant shifts every
expectation alike); the samples carry the subsidy all the same, so they are the decision's own numbers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from services.fleet.dro import SUPPORT_KINDS, DroInputError, SupportKind, get_divergence, worst_case
from services.fleet.dro.inputs import check_alpha

__all__ = [
    "TIE_RTOL",
    "FleetInputError",
    "Sense",
    "FleetMethod",
    "ChoiceStatus",
    "Ambiguity",
    "CostModel",
    "DayOutcomes",
    "SizeRow",
    "SizeTable",
    "CandidateRow",
    "CandidateTable",
    "Choice",
    "RollingHour",
    "FleetPlan",
    "size_table",
    "total_cost_samples",
    "completion_samples",
    "candidate_table",
    "choose",
    "similar_days",
    "rolling_hour",
    "plan_fleet",
    "SubsidyPoint",
    "subsidy_sweep",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Sense = Literal["min", "max"]
"""``"min"``: lower is better (cost); ``"max"``: higher is better (completion rate)."""
FleetMethod = Literal["deterministic", "dro", "dro_rh", "box_lp"]
ChoiceStatus = Literal["unique", "tie"]
"""``unique``: one size attains the optimum; ``tie``: several do (within ``TIE_RTOL``), the smallest won."""

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

    Defaults are docs/METHOD.md section 8's: Kullback-Leibler, α = 0.05, ``w = 10`` equal-width bins.
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
class CostModel:
    """The platform's cost per hour: Step 3 cost (already in CNY) plus ζ per instrumented vehicle-hour.

    ``interval_hours`` is the length of one sensing interval (the samples are per interval).
    """

    subsidy_cny_per_vehicle_hour: float = 0.0
    interval_hours: float = 1.0

    def __post_init__(self) -> None:
        z, tau = self.subsidy_cny_per_vehicle_hour, self.interval_hours
        if not (isinstance(z, int | float) and math.isfinite(z) and z >= 0):
            raise FleetInputError("subsidy_cny_per_vehicle_hour", f"must be finite and >= 0, got {z!r}")
        if not (isinstance(tau, int | float) and math.isfinite(tau) and tau > 0):
            raise FleetInputError("interval_hours", f"must be positive, got {tau!r}")


@dataclass(frozen=True, slots=True)
class DayOutcomes:
    """What the runs of one candidate size gave on ``M`` demand days of ``H`` intervals each.

    ``cost_cny[j, h]``: Step 3 monitoring cost in interval ``h`` of day ``j``; ``tasks_due[j, h]``: the POI
    tasks scheduled in interval ``h`` that can still be reached within the horizon; ``tasks_done[j, h]``:
    how many of those were completed within it.
    """

    cost_cny: FloatArray
    tasks_due: IntArray
    tasks_done: IntArray

    @classmethod
    def of(cls, cost_cny: ArrayLike, tasks_due: ArrayLike, tasks_done: ArrayLike) -> DayOutcomes:
        """Checked arrays: finite non-negative costs, ``0 <= done <= due``, all of one ``(M, H)`` shape."""
        c = np.asarray(cost_cny, dtype=np.float64)
        due = np.asarray(tasks_due, dtype=np.int64)
        done = np.asarray(tasks_done, dtype=np.int64)
        if c.ndim != 2 or c.shape[0] < 1 or c.shape[1] < 1:
            raise FleetInputError("samples", f"cost needs a (days, hours) array, got shape {c.shape}")
        if due.shape != c.shape or done.shape != c.shape:
            raise FleetInputError(
                "samples", f"tasks_due {due.shape} and tasks_done {done.shape} must match cost {c.shape}"
            )
        if not np.all(np.isfinite(c)) or np.any(c < 0):
            raise FleetInputError("samples", "costs must be finite and non-negative")
        if np.any(done < 0) or np.any(done > due):
            raise FleetInputError("samples", "need 0 <= tasks_done <= tasks_due")
        return cls(c, due, done)

    @property
    def n_days(self) -> int:
        """``M``."""
        return int(self.cost_cny.shape[0])

    @property
    def n_hours(self) -> int:
        """``H``, the intervals of the horizon."""
        return int(self.cost_cny.shape[1])


@dataclass(frozen=True, slots=True)
class SizeRow:
    """One candidate size of one KPI: sample mean, worst-case expectation, their difference, radius, cells.

    ``premium = worst_case - mean`` (negative or zero for ``sense="max"``, where the worst case is the
    infimum). ``status`` is the engine's (``optimal``, ``saturated`` or ``degenerate``).
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
class CandidateRow:
    """One candidate size for one decision: total cost per hour (mean, exact worst case, box LP worst case),
    the per-vehicle design KPI (the same divided by ``size``) and the completion rate on reachable tasks
    (mean and worst case, ``None`` without tasks)."""

    size: int
    cost: SizeRow  # total cost per hour, CNY
    box_lp_worst_case: float
    design_kpi_mean: float
    design_kpi_worst_case: float
    completion: SizeRow | None  # sense "max": worst_case is the infimum


@dataclass(frozen=True, slots=True)
class CandidateTable:
    """Rows of every candidate size (ascending) and the samples behind them.

    ``cost_samples[x]`` are the total costs per hour the worst cases were computed from;
    ``completion_samples[x]`` the completion rates (``None`` without tasks). ``days`` are the indices of
    the history days used (all of them, or the DRO_RH selection).
    """

    rows: tuple[CandidateRow, ...]
    days: tuple[int, ...]
    cost_samples: Mapping[int, FloatArray]
    completion_samples: Mapping[int, FloatArray] | None

    @property
    def sizes(self) -> tuple[int, ...]:
        """The candidate sizes, ascending."""
        return tuple(r.size for r in self.rows)

    def row(self, size: int) -> CandidateRow:
        """The row of ``size`` (``KeyError`` if it is not a candidate)."""
        for r in self.rows:
            if r.size == size:
                return r
        raise KeyError(size)


@dataclass(frozen=True, slots=True)
class Choice:
    """A chosen size: the method, the size, its objective (mean, worst case or box LP value of the total cost
    per hour), the tied sizes and, with a completion target, whether the size meets it."""

    method: FleetMethod
    size: int
    objective: float
    tied: tuple[int, ...]  # every size within TIE_RTOL of the optimum among the eligible, ascending
    status: ChoiceStatus
    target_met: bool | None = None  # None: no target


@dataclass(frozen=True, slots=True)
class RollingHour:
    """DRO_RH for interval ``hour``: how many observed hours it conditioned on, the table (with the days
    kept) and the choice."""

    hour: int
    observed_hours: int
    table: CandidateTable
    choice: Choice


@dataclass(frozen=True, slots=True)
class FleetPlan:
    """Everything one solve decides: the daily table with Deterministic, DRO and the box LP's choice, and
    DRO_RH for every hour of the horizon (conditioned on the hours observed so far)."""

    daily: CandidateTable
    deterministic: Choice
    dro: Choice
    box_lp: Choice
    rolling: tuple[RollingHour, ...]
    costs: CostModel
    target: float | None

    @property
    def rolling_sizes(self) -> tuple[int, ...]:
        """DRO_RH's size for every hour."""
        return tuple(r.choice.size for r in self.rolling)

    def point(self, hour: int) -> SubsidyPoint:
        """This plan's point on the subsidy trade-off curve for interval ``hour``: what
        :func:`subsidy_sweep` decides at ``costs``' subsidy from the same inputs."""
        rh = self.rolling[hour].choice
        return SubsidyPoint(self.costs.subsidy_cny_per_vehicle_hour, self.deterministic, self.dro, rh)


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


def _check_target(target: float | None) -> float | None:
    if target is None:
        return None
    t = float(target)
    if not (math.isfinite(t) and 0.0 <= t <= 1.0):
        raise FleetInputError("target", f"must be a completion rate in [0, 1], got {target!r}")
    return t


def _check_outcomes(outcomes: Mapping[int, DayOutcomes]) -> list[tuple[int, DayOutcomes]]:
    if not outcomes:
        raise FleetInputError("samples", "no candidate sizes")
    out = sorted(((_check_size(x), o) for x, o in outcomes.items()), key=lambda item: item[0])
    shapes = {o.cost_cny.shape for _, o in out}
    if len(shapes) != 1:
        raise FleetInputError("samples", f"sizes have different (days, hours) shapes: {sorted(shapes)}")
    return out


# ------------------------------------------------------------------------------------------- tables


def _row(x: int, f: FloatArray, amb: Ambiguity, sign: float, method: str = "exact") -> SizeRow:
    try:
        wc = worst_case(
            sign * f, amb.divergence, alpha=amb.alpha, support=amb.support, bins=amb.bins, method=method
        )
    except DroInputError as exc:
        raise FleetInputError(exc.parameter, f"size {x}: {exc.message}") from None
    value, mean = sign * float(wc.value), float(np.mean(f))
    return SizeRow(x, int(f.size), mean, value, value - mean, float(wc.rho), int(wc.m), str(wc.status))


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
    rows = tuple(_row(x, f, amb, sign) for x, f in _sorted_samples(samples, 2))
    return SizeTable(rows, amb, sense)


def total_cost_samples(
    outcomes: DayOutcomes, size: int, costs: CostModel, hour: int | None = None
) -> FloatArray:
    """The platform's total cost per hour on every day (docs/METHOD.md section 7):
    ``Σ_h cost_{j,h} / (H τ) + ζ x`` for the whole horizon (``hour=None``), ``cost_{j,h} / τ + ζ x`` for
    one interval."""
    tau, zeta = costs.interval_hours, costs.subsidy_cny_per_vehicle_hour
    c = outcomes.cost_cny
    per_hour = c.sum(axis=1) / (c.shape[1] * tau) if hour is None else c[:, hour] / tau
    return np.asarray(per_hour + zeta * size, dtype=np.float64)


def completion_samples(outcomes: DayOutcomes, hour: int | None = None) -> FloatArray | None:
    """Per day, the share of reachable tasks completed within the horizon (of the whole horizon, or of the
    tasks due in one interval); ``None`` when no day has a task due. A day with nothing due counts 1: it
    missed nothing."""
    due = outcomes.tasks_due.sum(axis=1) if hour is None else outcomes.tasks_due[:, hour]
    done = outcomes.tasks_done.sum(axis=1) if hour is None else outcomes.tasks_done[:, hour]
    if not np.any(due > 0):
        return None
    return np.where(due > 0, done / np.maximum(due, 1), 1.0).astype(np.float64)


def candidate_table(
    outcomes: Mapping[int, DayOutcomes],
    ambiguity: Ambiguity | None = None,
    costs: CostModel | None = None,
    *,
    hour: int | None = None,
    days: Sequence[int] | None = None,
) -> CandidateTable:
    """Every candidate's total cost per hour (mean, exact and box LP worst cases), design KPI and completion,
    for the whole horizon (``hour=None``) or one interval, on all days or on ``days`` (indices)."""
    amb, cm = ambiguity or Ambiguity(), costs or CostModel()
    items = _check_outcomes(outcomes)
    n_days = items[0][1].n_days
    keep = tuple(range(n_days)) if days is None else tuple(sorted({int(d) for d in days}))
    if len(keep) < 2 or keep[0] < 0 or keep[-1] >= n_days:
        raise FleetInputError("days", f"need at least 2 day indices in [0, {n_days}), got {keep}")
    if hour is not None and not 0 <= hour < items[0][1].n_hours:
        raise FleetInputError("hour", f"must lie in [0, {items[0][1].n_hours}), got {hour}")
    idx = np.asarray(keep, dtype=np.int64)
    rows, cost_s, comp_s = [], {}, {}
    for x, o in items:
        f = total_cost_samples(o, x, cm, hour)[idx]
        c_all = completion_samples(o, hour)
        cost_row = _row(x, f, amb, 1.0)
        box = _row(x, f, amb, 1.0, "box_lp").worst_case if amb.support == "binned" else math.nan
        comp_row = None
        if c_all is not None:
            c = c_all[idx]
            comp_s[x] = c
            comp_row = _row(x, c, amb, -1.0)
        cost_s[x] = f
        rows.append(CandidateRow(x, cost_row, box, cost_row.mean / x, cost_row.worst_case / x, comp_row))
    has_tasks = all(r.completion is not None for r in rows)
    return CandidateTable(tuple(rows), keep, cost_s, comp_s if has_tasks else None)


# ------------------------------------------------------------------------------------------- choices


def _tied(values: Sequence[float]) -> list[int]:
    """Indices of the values within ``TIE_RTOL`` of the minimum."""
    best = min(values)
    return [i for i, v in enumerate(values) if v == best or math.isclose(v, best, rel_tol=TIE_RTOL)]


def choose(table: CandidateTable, method: FleetMethod, target: float | None = None) -> Choice:
    """The size ``method`` picks from ``table`` (ties: the smallest).

    Deterministic minimizes the mean total cost, DRO and DRO_RH the exact worst case, ``box_lp`` the
    paper's Eq. (28) value. With a completion ``target`` only sizes whose completion (the mean for
    Deterministic, the worst case otherwise) reaches it are eligible; if none does, the size with the best
    such completion is taken (ties: the cheaper objective, then the smaller) and ``target_met`` is False.
    """
    t = _check_target(target)

    def objective(r: CandidateRow) -> float:
        if method == "deterministic":
            return r.cost.mean
        if method == "box_lp":
            return r.box_lp_worst_case
        return r.cost.worst_case

    def completion(r: CandidateRow) -> float:
        assert r.completion is not None
        return r.completion.mean if method == "deterministic" else r.completion.worst_case

    rows = list(table.rows)
    met: bool | None = None
    if t is not None and all(r.completion is not None for r in rows):
        eligible = [r for r in rows if completion(r) >= t]
        met = bool(eligible)
        if not eligible:
            best = max(completion(r) for r in rows)
            rows = [
                r
                for r in rows
                if completion(r) == best or math.isclose(completion(r), best, rel_tol=TIE_RTOL)
            ]
        else:
            rows = eligible
    values = [objective(r) for r in rows]
    tied = _tied(values)
    first = rows[tied[0]]
    return Choice(
        method=method,
        size=first.size,
        objective=objective(first),
        tied=tuple(rows[i].size for i in tied),
        status="tie" if len(tied) > 1 else "unique",
        target_met=met,
    )


# ----------------------------------------------------------------------------------- rolling horizon


def similar_days(volumes: ArrayLike, observed: ArrayLike, keep: int) -> tuple[int, ...]:
    """The ``keep`` history days most like the day so far (ascending indices).

    ``volumes[j, h]``: requests of history day ``j`` in interval ``h``; ``observed``: the requests of the
    current day in its first ``k`` intervals (the hours already past). Distance of day ``j``:
    ``sqrt(mean_{h<k} (log(1 + observed_h) - log(1 + volumes[j, h]))^2)``, the root-mean-square relative
    difference of the hourly volumes; ties go to the lower index. With nothing observed (``k = 0``) every
    day is kept: there is nothing to condition on yet.
    """
    v = np.asarray(volumes, dtype=np.float64)
    obs = np.asarray(observed, dtype=np.float64).reshape(-1)
    if v.ndim != 2 or v.shape[0] < 1:
        raise FleetInputError("volumes", f"need a (days, hours) array, got shape {v.shape}")
    if obs.size > v.shape[1] or not np.all(np.isfinite(obs)) or np.any(obs < 0):
        raise FleetInputError(
            "observed", f"need at most {v.shape[1]} non-negative volumes, got {obs.tolist()}"
        )
    if not np.all(np.isfinite(v)) or np.any(v < 0):
        raise FleetInputError("volumes", "volumes must be finite and non-negative")
    if isinstance(keep, bool) or not isinstance(keep, int) or keep < 2:
        raise FleetInputError("keep", f"must be an integer >= 2, got {keep!r}")
    n = v.shape[0]
    if obs.size == 0 or keep >= n:
        return tuple(range(n))
    d = np.sqrt(np.mean((np.log1p(obs)[None, :] - np.log1p(v[:, : obs.size])) ** 2, axis=1))
    order = sorted(range(n), key=lambda j: (float(d[j]), j))
    return tuple(sorted(order[:keep]))


def rolling_hour(
    outcomes: Mapping[int, DayOutcomes],
    volumes: ArrayLike,
    observed: ArrayLike,
    hour: int,
    *,
    keep: int,
    ambiguity: Ambiguity | None = None,
    costs: CostModel | None = None,
    target: float | None = None,
) -> RollingHour:
    """DRO_RH's decision for interval ``hour`` given the current day's volumes of its first intervals:
    conditions on the observed intervals before ``hour`` (:func:`similar_days`) and minimizes the worst
    case of that interval's total cost on the kept days."""
    obs = np.asarray(observed, dtype=np.float64).reshape(-1)
    k = min(int(hour), int(obs.size))
    days = similar_days(volumes, obs[:k], keep)
    table = candidate_table(outcomes, ambiguity, costs, hour=hour, days=days)
    return RollingHour(hour, k, table, choose(table, "dro_rh", target))


def plan_fleet(
    outcomes: Mapping[int, DayOutcomes],
    volumes: ArrayLike,
    ambiguity: Ambiguity | None = None,
    costs: CostModel | None = None,
    *,
    observed: ArrayLike = (),
    keep: int = 7,
    target: float | None = None,
) -> FleetPlan:
    """One solve: Deterministic, DRO and the box LP on the daily total cost per hour, DRO_RH on every
    interval conditioned on the ``observed`` volumes of the current day (its first intervals).

    Parameters
    ----------
    outcomes
        ``outcomes[x]``: the runs of size ``x`` on the ``M`` history days.
    volumes
        ``(M, H)`` requests of every history day and interval (the conditioning features).
    observed
        Requests of the current day in its first ``k < H`` intervals (empty before the day starts).
    keep
        Days DRO_RH keeps after conditioning (all when ``keep >= M``).
    target
        Optional completion-rate target on the reachable tasks.
    """
    amb, cm = ambiguity or Ambiguity(), costs or CostModel()
    t = _check_target(target)
    items = _check_outcomes(outcomes)
    v = np.asarray(volumes, dtype=np.float64)
    if v.shape != items[0][1].cost_cny.shape:
        raise FleetInputError("volumes", f"need shape {items[0][1].cost_cny.shape}, got {v.shape}")
    daily = candidate_table(outcomes, amb, cm)
    rolling = tuple(
        rolling_hour(outcomes, v, observed, h, keep=keep, ambiguity=amb, costs=cm, target=t)
        for h in range(items[0][1].n_hours)
    )
    return FleetPlan(
        daily=daily,
        deterministic=choose(daily, "deterministic", t),
        dro=choose(daily, "dro", t),
        box_lp=choose(daily, "box_lp", t),
        rolling=rolling,
        costs=cm,
        target=t,
    )


# ------------------------------------------------------------------------------------- subsidy sweep


@dataclass(frozen=True, slots=True)
class SubsidyPoint:
    """What each method chooses at one subsidy ζ (CNY per instrumented vehicle-hour), from the same samples:
    Deterministic and DRO for the day, DRO_RH for the hour the sweep was asked for."""

    subsidy_cny_per_vehicle_hour: float
    deterministic: Choice
    dro: Choice
    dro_rh: Choice


def subsidy_sweep(
    outcomes: Mapping[int, DayOutcomes],
    volumes: ArrayLike,
    subsidies: Sequence[float],
    *,
    hour: int,
    ambiguity: Ambiguity | None = None,
    interval_hours: float = 1.0,
    observed: ArrayLike = (),
    keep: int = 7,
    target: float | None = None,
) -> tuple[SubsidyPoint, ...]:
    """The trade-off curve: every method's choice at each of ``subsidies`` (ascending, duplicates once).

    Each point is decided exactly as :func:`plan_fleet` decides with ``CostModel(ζ, interval_hours)``: the
    same outcomes, the same conditioning of DRO_RH on ``observed`` for interval ``hour``, the same
    ``target``. Because ζ x shifts every sample of size ``x`` alike, the chosen size never grows with ζ.

    Raises
    ------
    FleetInputError
        A subsidy that is negative or not finite, or any input :func:`plan_fleet` would refuse.
    """
    amb = ambiguity or Ambiguity()
    t = _check_target(target)
    items = _check_outcomes(outcomes)
    v = np.asarray(volumes, dtype=np.float64)
    if v.shape != items[0][1].cost_cny.shape:
        raise FleetInputError("volumes", f"need shape {items[0][1].cost_cny.shape}, got {v.shape}")
    points = []
    for z in sorted({float(z) for z in subsidies}):
        cm = CostModel(z, interval_hours)
        daily = candidate_table(outcomes, amb, cm)
        rh = rolling_hour(outcomes, v, observed, hour, keep=keep, ambiguity=amb, costs=cm, target=t)
        points.append(SubsidyPoint(z, choose(daily, "deterministic", t), choose(daily, "dro", t), rh.choice))
    return tuple(points)
