"""A served city: network, grid, sensing horizon, weights and dispatch parameters."""

from __future__ import annotations

import datetime as dt
import math
import re
from dataclasses import dataclass, field
from zoneinfo import ZoneInfo

import numpy as np
from numpy.typing import NDArray

from services.model import IntervalKey
from services.network.network import Network
from services.rfc3339 import parse_rfc3339
from services.sensing.grid import EdgeCells, Grid

__all__ = ["Horizon", "DispatchParams", "FleetParams", "City"]

_LABEL = re.compile(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}$")


@dataclass(frozen=True, slots=True)
class Horizon:
    """Operating horizon: ``n_intervals`` sensing intervals of ``interval_s`` from ``start`` local time.

    Interval keys are global: ``k = floor((local_seconds - start_offset) / interval_s)`` where local seconds
    count from 1970-01-01T00:00 local wall time; ``interval_s`` divides a day, so ``k mod per_day`` is the
    position within the day and the interval is in the horizon iff that position is below ``n_intervals``.
    """

    timezone: str = "Asia/Shanghai"
    start: dt.time = dt.time(8, 0)
    interval_s: int = 3600
    n_intervals: int = 4
    epoch_s: int = 200

    def __post_init__(self) -> None:
        if self.interval_s <= 0 or 86400 % self.interval_s:
            raise ValueError("interval_s must divide a day (86400 s)")
        if not 1 <= self.n_intervals <= 86400 // self.interval_s:
            raise ValueError("n_intervals must fit in a day")
        if self.epoch_s <= 0:
            raise ValueError("epoch_s must be positive")
        ZoneInfo(self.timezone)

    @property
    def per_day(self) -> int:
        return 86400 // self.interval_s

    def _start_offset_s(self) -> int:
        return self.start.hour * 3600 + self.start.minute * 60 + self.start.second

    def interval_of(self, time_s: float) -> IntervalKey:
        """The interval containing POSIX time ``time_s``."""
        return IntervalKey(int(np.floor((time_s + self.shift_s(time_s)) / self.interval_s)))

    def shift_s(self, time_s: float) -> float:
        """UTC offset at ``time_s`` minus the horizon start: ``k = floor((t + shift) / interval_s)``."""
        utc = dt.datetime.fromtimestamp(float(time_s), tz=dt.UTC)
        offset = utc.astimezone(ZoneInfo(self.timezone)).utcoffset()
        return (offset.total_seconds() if offset else 0.0) - self._start_offset_s()

    def intervals_of(self, times_s: NDArray[np.float64]) -> NDArray[np.int64]:
        """Vectorized ``interval_of`` using the UTC offset in force at ``times_s[0]`` (paths last minutes,
        and time-zone transitions happen at night, outside any sensible horizon)."""
        if len(times_s) == 0:
            return np.zeros(0, dtype=np.int64)
        shift = self.shift_s(float(times_s[0]))
        return np.floor((np.asarray(times_s, dtype=np.float64) + shift) / self.interval_s).astype(np.int64)

    def in_horizon(self, k: int) -> bool:
        return (k % self.per_day) < self.n_intervals

    def position(self, k: int) -> int:
        """Index of interval ``k`` within its day's horizon (0..n_intervals-1 when in the horizon)."""
        return k % self.per_day

    def local_start(self, k: int) -> dt.datetime:
        """Naive local wall-clock start of interval ``k``."""
        local_s = k * self.interval_s + self._start_offset_s()
        return dt.datetime(1970, 1, 1) + dt.timedelta(seconds=local_s)

    def label(self, k: int) -> str:
        """Human label of interval ``k``: its local start, ``YYYY-MM-DDTHH:MM``."""
        return self.local_start(k).strftime("%Y-%m-%dT%H:%M")

    def interval_start_s(self, k: int) -> float:
        """POSIX time at which interval ``k`` starts: its local wall-clock start in the time zone."""
        return self.local_start(k).replace(tzinfo=ZoneInfo(self.timezone)).timestamp()

    def interval_of_label(self, label: str) -> IntervalKey:
        """The interval whose label (:meth:`label`, its local start ``YYYY-MM-DDTHH:MM``) is ``label``.

        Raises
        ------
        ValueError
            If ``label`` is not a date and time, or not the start of an interval (the message names the
            start of the interval it falls in).
        """
        try:
            local = dt.datetime.strptime(label, "%Y-%m-%dT%H:%M")
        except ValueError:
            raise ValueError("not a valid date and time") from None
        local_s = (local - dt.datetime(1970, 1, 1)).total_seconds()
        k = IntervalKey(math.floor((local_s - self._start_offset_s()) / self.interval_s))
        try:
            start = self.label(k)
        except OverflowError:  # the interval it falls in starts before year 1
            raise ValueError(f"{label} is not the start of an interval") from None
        if start != label:
            raise ValueError(f"{label} is not the start of an interval (e.g. {start})")
        return k

    def parse_interval(self, text: str) -> IntervalKey:
        """An interval from its label (``YYYY-MM-DDTHH:MM``, local start) or any RFC 3339 time inside it.

        Raises
        ------
        ValueError
            With a message for the caller: not a label of an interval start, not an RFC 3339 time.
        """
        if _LABEL.match(text):
            return self.interval_of_label(text)
        try:
            when = parse_rfc3339(text)
        except ValueError as exc:
            raise ValueError(
                f"give a label YYYY-MM-DDTHH:MM or an RFC 3339 time with an offset ({exc})"
            ) from None
        return self.interval_of(when.timestamp())

    def start_s(self, date: str | dt.date) -> float:
        """POSIX time of the horizon's start on local calendar day ``date`` (``YYYY-MM-DD``)."""
        day = dt.date.fromisoformat(date) if isinstance(date, str) else date
        return dt.datetime.combine(day, self.start, tzinfo=ZoneInfo(self.timezone)).timestamp()

    @property
    def length_s(self) -> int:
        """Length of the operating horizon (``n_intervals * interval_s``)."""
        return self.n_intervals * self.interval_s

    def coming_interval(self, now_s: float) -> IntervalKey:
        """The first interval of the operating horizon that starts after ``now_s`` (today's next hour of
        the horizon, or the first hour of the next day's): the hour a fleet solve at ``now_s`` is for."""
        k = int(self.interval_of(now_s)) + 1
        for _ in range(self.per_day):
            if self.in_horizon(k):
                return IntervalKey(k)
            k += 1
        raise AssertionError("a day always holds a horizon interval")

    def day_intervals(self, k: int) -> list[IntervalKey]:
        """The horizon intervals of the day that interval ``k`` belongs to."""
        first = k - (k % self.per_day)
        return [IntervalKey(first + i) for i in range(self.n_intervals)]


@dataclass(frozen=True, slots=True)
class DispatchParams:
    """Dispatch parameters of docs/METHOD.md sections 3-7 (defaults are the paper's)."""

    rho: float = 0.2
    radius_m: float = 2000.0
    speed_kmh: float = 35.0
    kappas: tuple[float, ...] = (0.0, 0.3, 0.6, 0.9)
    max_iter: int = 5
    patience_s: float = 600.0
    snap_limit_m: float = 500.0
    unit_cost_cny_per_km: float = 1.5
    subsidy_cny_per_vehicle_hour: float = 0.0
    active_sensing: bool = True  # Step 3 on/off
    step3_reach_s: float | None = (
        900.0  # Step 3: a POI considers the taxis within this travel time (None: all)
    )
    step3_reach_above_s: float = (
        3600.0  # ... on networks that take longer than this to cross (docs/METHOD.md)
    )

    def __post_init__(self) -> None:
        if not 0.0 < self.rho < 1.0:
            raise ValueError("rho must lie in (0, 1)")
        if self.radius_m <= 0 or self.speed_kmh <= 0 or self.patience_s < 0 or self.snap_limit_m <= 0:
            raise ValueError("radius, speed, snap limit must be positive and patience non-negative")
        if not self.kappas or 0.0 not in self.kappas or any(not 0.0 <= k < 1.0 for k in self.kappas):
            raise ValueError("kappas must contain 0 and lie in [0, 1)")
        if self.max_iter < 0:
            raise ValueError("max_iter must be non-negative")
        if (
            self.step3_reach_s is not None and not self.step3_reach_s > 0
        ) or not self.step3_reach_above_s >= 0:
            raise ValueError(
                "step3_reach_s must be positive (or null: no reach), step3_reach_above_s non-negative"
            )


@dataclass(frozen=True, slots=True)
class FleetParams:
    """The city's fleet-sizing parameters (``city.json`` ``fleet``; docs/FLEET.md, "Per city"). A field left
    ``None`` is derived from the fleet the platform posted (``sizes``, ``n0``) or taken from the worker's
    settings (``days``, ``subsidy_cny_per_vehicle_hour``, ``completion_target``; a target of 0 is met by
    every size: off). ``synthetic_history`` marks a demo city whose bundle carries a demand generator: it
    is sized on that generator's seeded days until it has M recorded days (any other city waits for
    them)."""

    sizes: tuple[int, ...] | None = None  # candidate instrumented fleet sizes N1
    n0: int | None = None  # ordinary taxis in every simulated day
    days: int | None = None  # M: days of history per solve
    subsidy_cny_per_vehicle_hour: float | None = None  # ζ
    completion_target: float | None = None
    synthetic_history: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.synthetic_history, bool):
            raise ValueError(f"fleet.synthetic_history must be true or false, got {self.synthetic_history!r}")
        if self.sizes is not None and (
            not self.sizes
            or any(isinstance(x, bool) or not isinstance(x, int) or x < 1 for x in self.sizes)
            or len(set(self.sizes)) != len(self.sizes)
        ):
            raise ValueError(f"fleet.sizes must be distinct positive integers, got {list(self.sizes)}")
        if self.n0 is not None and (isinstance(self.n0, bool) or not isinstance(self.n0, int) or self.n0 < 0):
            raise ValueError(f"fleet.n0 must be a non-negative integer, got {self.n0!r}")
        if self.days is not None and (
            isinstance(self.days, bool) or not isinstance(self.days, int) or not 2 <= self.days <= 366
        ):
            raise ValueError(f"fleet.days must be an integer in 2..366, got {self.days!r}")
        zeta = self.subsidy_cny_per_vehicle_hour
        if zeta is not None and not (isinstance(zeta, int | float) and math.isfinite(zeta) and zeta >= 0):
            raise ValueError(
                f"fleet.subsidy_cny_per_vehicle_hour must be a non-negative number, got {zeta!r}"
            )
        target = self.completion_target
        if target is not None and not (isinstance(target, int | float) and 0.0 <= target <= 1.0):
            raise ValueError(f"fleet.completion_target must lie in [0, 1], got {target!r}")

    def to_json(self) -> dict[str, object]:
        """The ``city.json`` object: the fields set."""
        out: dict[str, object] = {}
        for name in ("sizes", "n0", "days", "subsidy_cny_per_vehicle_hour", "completion_target"):
            value = getattr(self, name)
            if value is not None:
                out[name] = list(value) if isinstance(value, tuple) else value
        if self.synthetic_history:
            out["synthetic_history"] = True
        return out


@dataclass(frozen=True, slots=True, eq=False)
class City:
    """Everything the core needs to serve one city.

    ``cell_weight[c]`` is s_g (sums to 1 over the cells the network touches, 0 elsewhere);
    ``interval_weight[i]`` is mu_t for position ``i`` of the horizon (sums to 1).
    """

    name: str
    network: Network
    grid: Grid
    edge_cells: EdgeCells
    horizon: Horizon = field(default_factory=Horizon)
    params: DispatchParams = field(default_factory=DispatchParams)
    cell_weight: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    interval_weight: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    source: str = ""  # attribution / provenance line
    fleet: FleetParams = field(default_factory=FleetParams)

    @property
    def n_cells_touched(self) -> int:
        """Cells the network touches (``s_g > 0``): the denominator of the coverage rate."""
        return int(np.count_nonzero(self.cell_weight > 0))

    def mu(self, k: int) -> float:
        """mu_t of interval ``k`` (0 outside the operating horizon)."""
        if not self.horizon.in_horizon(k):
            return 0.0
        return float(self.interval_weight[self.horizon.position(k)])
