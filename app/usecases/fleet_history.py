"""The platform's history as the fleet sizing reads it (docs/FLEET.md, "The platform's history"): the days
of epochs the service recorded for a city, each day's requests and the fleet it ran, how many of the M days
a solve needs there are, and the sizing configuration of a city (the worker's settings, the city's own
values on top). The API's status and the worker's solve (``app.usecases.fleet_solve``) share it.

Every committed epoch records its riders, how many instrumented and ordinary taxis it posted and, when it
opens the day's horizon, where each of them stood (``app.usecases.epochs``), under the city's local day. A
rider who waits recurs in every epoch until matched or gone, so riders are deduplicated by id, keeping the
first request time seen; node ids become network indices.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol
from zoneinfo import ZoneInfo

import numpy as np
from numpy.typing import NDArray

from app.ports import WorkerStore
from services.city import City, FleetParams
from services.fleet.sizing import Ambiguity
from services.network.network import SnapError
from services.sim.demand import DemandSet, Request

if TYPE_CHECKING:
    from app.settings import SizingSettings

__all__ = [
    "DemandLog",
    "RECORDED_GENERATOR",
    "RecordedDemandError",
    "RecordedFleet",
    "RecordedDay",
    "HistoryState",
    "day_key",
    "demand_from_records",
    "day_from_records",
    "recorded_days",
    "history_state",
    "posted_fleet",
    "start_nodes",
    "SIZE_SPREAD",
    "spread_sizes",
    "SizingConfig",
    "FleetHistory",
]

RECORDED_GENERATOR = "recorded"


class DemandLog(Protocol):
    """Where the records of the epochs are read (the store, through the fleet use cases)."""

    def recorded_day(self, city: City, day: dt.date) -> list[str]:
        """The records of the epochs of the city's local ``day``, in commit order."""
        ...

    def recorded_epoch_counts(self, city: City, days: Sequence[dt.date]) -> list[int]:
        """How many epochs each of the local ``days`` recorded (without reading them)."""
        ...


def day_key(day: dt.date) -> str:
    """A local day as the store keys its records: ``YYYYMMDD`` (``app.ports.local_day``)."""
    return day.strftime("%Y%m%d")


class RecordedDemandError(ValueError):
    """A recorded epoch cannot be read (the message names the day and the epoch)."""


@dataclass(frozen=True, slots=True, eq=False)
class RecordedFleet:
    """The fleet a recorded day ran: how many instrumented and ordinary taxis its epochs posted, and the
    network nodes where they stood when the horizon opened (``None``: the day has no opening epoch)."""

    instrumented: int
    ordinary: int
    instrumented_nodes: NDArray[np.int64] | None = None
    ordinary_nodes: NDArray[np.int64] | None = None


@dataclass(frozen=True, slots=True)
class RecordedDay:
    """One local day of the platform's history: its requests and its fleet (``None``: its records carry
    no fleet)."""

    date: dt.date
    demand: DemandSet
    fleet: RecordedFleet | None


@dataclass(frozen=True, slots=True)
class HistoryState:
    """How much history a city has for a solve of an hour of local day ``day``: ``days`` of the ``needed``
    (M) in the ``lookback_days`` before it. With every later day recorded too, a first solve is possible
    on ``first_solve_on``."""

    day: dt.date
    days: int
    needed: int
    lookback_days: int

    @property
    def enough(self) -> bool:
        """Whether a solve today has its M days."""
        return self.days >= self.needed

    @property
    def first_solve_on(self) -> dt.date:
        """The first local day whose solves have M recorded days before them, if the platform posts epochs
        on every day from ``day`` on (``day`` when it has them already)."""
        return self.day + dt.timedelta(days=max(0, self.needed - self.days))

    def describe(self) -> str:
        """``collecting history: k of M days ...`` (or that the history is complete)."""
        if self.enough:
            return f"history complete: the last {self.needed} days with epochs before {self.day}"
        return (
            f"collecting history: {self.days} of {self.needed} days (local days with epochs in the "
            f"{self.lookback_days} days before {self.day}); a first solve is possible on "
            f"{self.first_solve_on} if epochs are posted every day until then"
        )


def _nodes(city: City, ids: Any, where: str) -> NDArray[np.int64]:
    """Node ids as network indices (an id the network does not know is left out)."""
    if not isinstance(ids, list):
        raise RecordedDemandError(f"{where}: fleet positions are not a list")
    out: list[int] = []
    for node in ids:
        try:
            out.append(city.network.index_of(int(node)))
        except SnapError:
            continue
        except (TypeError, ValueError):
            raise RecordedDemandError(f"{where}: bad node id {node!r}") from None
    return np.asarray(out, dtype=np.int64)


class _DayReader:
    """Reads one local day's records: requests deduplicated by id, the fleet posted."""

    def __init__(self, city: City, day: dt.date) -> None:
        self.city = city
        self.day = day
        self.tz = ZoneInfo(city.horizon.timezone)
        self.seen: dict[str, Request] = {}
        self.dropped: set[str] = set()
        self.epochs = self.rows = 0
        self.max_fleet: tuple[int, int] | None = None
        self.opening: tuple[float, RecordedFleet] | None = None

    def read(self, i: int, text: str) -> None:
        """One epoch's record."""
        try:
            doc = json.loads(text)
            riders = list(doc["riders"])
        except (ValueError, KeyError, TypeError) as exc:
            raise RecordedDemandError(
                f"{self.city.name}, {self.day}: record {i} is not recorded demand ({exc!r})"
            ) from None
        self.epochs += 1
        where = f"{self.city.name}, {self.day}: epoch {doc.get('epoch_id', i)!r}"
        for r in riders:
            self._rider(r, where)
        self._fleet(doc, where)

    def _rider(self, r: Any, where: str) -> None:
        self.rows += 1
        try:
            rid = str(r["id"])
            t = float(r["requested_at_s"])
            origin, dest = int(r["origin"]), int(r["destination"])
        except (ValueError, KeyError, TypeError) as exc:
            raise RecordedDemandError(f"{where}: bad rider ({exc!r})") from None
        if rid in self.seen or rid in self.dropped:
            return
        if not math.isfinite(t) or dt.datetime.fromtimestamp(t, tz=self.tz).date() != self.day:
            return
        try:
            o, d = self.city.network.index_of(origin), self.city.network.index_of(dest)
        except SnapError:
            self.dropped.add(rid)
            return
        self.seen[rid] = Request(rid, float(math.floor(t)), o, d)

    def _fleet(self, doc: dict[str, Any], where: str) -> None:
        fleet = doc.get("fleet")
        if fleet is None:  # a record written before the fleet was recorded
            return
        try:
            counts = (int(fleet["instrumented"]), int(fleet["ordinary"]))
            time_s = float(doc["time_s"])
        except (ValueError, KeyError, TypeError) as exc:
            raise RecordedDemandError(f"{where}: bad fleet ({exc!r})") from None
        top = self.max_fleet or (0, 0)
        self.max_fleet = (max(top[0], counts[0]), max(top[1], counts[1]))
        at_open = doc.get("fleet_at_open")
        if isinstance(at_open, dict) and (self.opening is None or time_s < self.opening[0]):
            inst = _nodes(self.city, at_open.get("instrumented"), where)
            ordn = _nodes(self.city, at_open.get("ordinary"), where)
            self.opening = (time_s, RecordedFleet(counts[0], counts[1], inst, ordn))

    def result(self) -> RecordedDay:
        requests = sorted(self.seen.values(), key=lambda r: (r.time_s, r.id))
        demand = DemandSet(
            city=self.city.name,
            date=self.day.isoformat(),
            requests=tuple(requests),
            generator=RECORDED_GENERATOR,
            seed=None,
            params={"epochs": self.epochs, "rider_rows": self.rows, "unknown_nodes": len(self.dropped)},
        )
        fleet = self.opening[1] if self.opening is not None else None
        if fleet is None and self.max_fleet is not None:
            fleet = RecordedFleet(*self.max_fleet)
        return RecordedDay(self.day, demand, fleet)


def day_from_records(city: City, date: str | dt.date, records: Iterable[str]) -> RecordedDay:
    """The requests and the fleet of the recorded epochs ``records`` of local day ``date``.

    Requests: riders deduplicated by id (the first request time seen is kept), times floored to whole
    seconds; riders requested on another local day are left out, and a rider whose origin or destination
    node the network does not know (the bundle was rebuilt since) is dropped and counted in
    ``params["unknown_nodes"]``. Fleet: the counts and positions of the epoch that opened the day's horizon;
    without one, the largest counts any epoch posted and no positions.

    Raises
    ------
    RecordedDemandError
        A record that is not the JSON the service records.
    """
    reader = _DayReader(city, dt.date.fromisoformat(date) if isinstance(date, str) else date)
    for i, text in enumerate(records):
        reader.read(i, text)
    return reader.result()


def demand_from_records(city: City, date: str | dt.date, records: Iterable[str]) -> DemandSet:
    """The requests of :func:`day_from_records` as a ``DemandSet``."""
    return day_from_records(city, date, records).demand


def recorded_days(
    source: DemandLog, city: City, before: dt.date, want: int, lookback_days: int
) -> list[RecordedDay]:
    """Up to ``want`` local days before ``before`` (newest first, within ``lookback_days``) on which the
    service committed at least one epoch."""
    days = [before - dt.timedelta(days=back) for back in range(1, lookback_days + 1)]
    counts = source.recorded_epoch_counts(city, days)
    found: list[RecordedDay] = []
    for day, n in zip(days, counts, strict=True):
        if n == 0:
            continue
        found.append(day_from_records(city, day, source.recorded_day(city, day)))
        if len(found) == want:
            break
    return found


def history_state(
    source: DemandLog, city: City, day: dt.date, needed: int, lookback_days: int
) -> HistoryState:
    """How many of the M days a solve for local day ``day`` needs the city has (one store round trip, no
    record read)."""
    days = [day - dt.timedelta(days=back) for back in range(1, lookback_days + 1)]
    have = sum(1 for n in source.recorded_epoch_counts(city, days) if n > 0)
    return HistoryState(day, min(have, needed), needed, lookback_days)


def posted_fleet(days: Sequence[RecordedDay]) -> tuple[int, int] | None:
    """The platform's fleet over recorded days: the median of the instrumented and of the ordinary taxis
    each day posted (rounded half up), over the days that recorded a fleet (``None``: none did)."""
    fleets = [d.fleet for d in days if d.fleet is not None]
    if not fleets:
        return None

    def median(values: list[int]) -> int:
        return int(math.floor(statistics.median(values) + 0.5))

    return median([f.instrumented for f in fleets]), median([f.ordinary for f in fleets])


_START_STREAM = 0xF1EE7


def start_nodes(fleet: RecordedFleet, day: dt.date, n1: int, n0: int, seed: int) -> NDArray[np.int64] | None:
    """Where a simulated fleet of ``n1`` instrumented and ``n0`` ordinary taxis starts on a recorded day
    (instrumented first), from where the day's taxis stood when its horizon opened; ``None`` when the day
    recorded no positions (the simulator then draws seeded random nodes).

    Each kind takes its own recorded positions (the other kind's when it has none): all of them in a
    seeded order when it has at most as many taxis as were posted, else all of them plus seeded draws
    among them for the rest, so the simulated fleet keeps the recorded spatial distribution.
    """
    inst, ordinary = fleet.instrumented_nodes, fleet.ordinary_nodes
    if inst is None or ordinary is None or inst.size + ordinary.size == 0:
        return None
    rng = np.random.default_rng(np.random.SeedSequence([seed, day.toordinal(), _START_STREAM]))

    def take(own: NDArray[np.int64], other: NDArray[np.int64], n: int) -> NDArray[np.int64]:
        pool = own if own.size else other
        if n <= pool.size:
            return pool[rng.permutation(pool.size)[:n]]
        return np.concatenate([pool, pool[rng.integers(pool.size, size=n - pool.size)]])

    return np.concatenate([take(inst, ordinary, n1), take(ordinary, inst, n0)]).astype(np.int64)


SIZE_SPREAD = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0)
"""The candidate sizes derived from the instrumented fleet posted, as fractions of it."""


def spread_sizes(posted: int) -> tuple[int, ...]:
    """Candidate instrumented fleet sizes around ``posted``: :data:`SIZE_SPREAD` of it, rounded half up,
    at least 1, distinct and ascending (e.g. 150 -> 38, 75, 113, 150, 225, 300)."""
    if posted < 1:
        raise ValueError("no instrumented fleet posted to spread sizes around")
    return tuple(sorted({max(1, int(f * posted + 0.5)) for f in SIZE_SPREAD}))


@dataclass(frozen=True, slots=True)
class SizingConfig:
    """What a solve simulates and how it decides: the worker's settings (``SD_WORKER_*``), and for one
    solve the city's own values on top of them (:meth:`for_city`, :meth:`with_fleet`)."""

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
    def from_settings(cls, sizing: SizingSettings, retention_s: int) -> SizingConfig:
        """The configuration the sizing settings describe (the group's fields are this class's, but for
        the four of the ambiguity set); recorded demand is looked for as far back as it is kept
        (``retention_s``)."""
        values = sizing.model_dump(exclude={"divergence", "alpha", "support", "bins"})
        values.update(sizes=tuple(sorted(sizing.sizes)), subsidy_sweep=tuple(sizing.subsidy_sweep))
        return cls(
            **values,
            ambiguity=Ambiguity(sizing.divergence, sizing.alpha, sizing.support, sizing.bins),
            lookback_days=max(1, retention_s // 86400 + 1),
        )

    def for_city(self, params: FleetParams) -> SizingConfig:
        """This configuration with the values the city's ``city.json`` sets (M, ζ, the target, and the
        sizes and N0 when set)."""
        return replace(
            self,
            days=self.days if params.days is None else params.days,
            subsidy_cny_per_vehicle_hour=(
                self.subsidy_cny_per_vehicle_hour
                if params.subsidy_cny_per_vehicle_hour is None
                else float(params.subsidy_cny_per_vehicle_hour)
            ),
            completion_target=(
                self.completion_target
                if params.completion_target is None
                else float(params.completion_target)
            ),
            sizes=self.sizes if params.sizes is None else tuple(sorted(params.sizes)),
            n0=self.n0 if params.n0 is None else params.n0,
        )


class FleetHistory:
    """The platform's history of a city as a solve reads it (the API's status and the worker share it):
    the records of the epochs by local day, how many of the M days a solve needs there are."""

    def __init__(self, store: WorkerStore, defaults: SizingConfig) -> None:
        self.store = store
        self.defaults = defaults

    def recorded_day(self, city: City, day: dt.date) -> list[str]:
        """The records of the epochs of the city's local ``day``, in commit order."""
        return self.store.recorded_demand(city.name, day_key(day))

    def recorded_epoch_counts(self, city: City, days: Sequence[dt.date]) -> list[int]:
        """How many epochs each of the local ``days`` recorded."""
        return self.store.recorded_epochs(city.name, [day_key(d) for d in days])

    def config(self, city: City) -> SizingConfig:
        """The worker's settings with the city's own values on top."""
        return self.defaults.for_city(city.fleet)

    def state(self, city: City, day: dt.date) -> HistoryState:
        """How many of the M days a solve for local day ``day`` needs the city has recorded."""
        cfg = self.config(city)
        return history_state(self, city, day, cfg.days, cfg.lookback_days)
