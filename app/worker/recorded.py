"""Recorded demand → demand sets: the requests the service saw on one local day, as the simulator takes them.

Every committed epoch's riders are recorded in the store (``EpochCommit.demand_json``, keyed by UTC day, see
``app.usecases.epochs``). A rider who waits recurs in every epoch until matched or gone, so
riders are deduplicated by id, keeping the first request time seen; node ids become network indices.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol
from zoneinfo import ZoneInfo

from services.city import City
from services.network.network import SnapError
from services.sim.demand import DemandSet, Request

__all__ = [
    "DemandLog",
    "RECORDED_GENERATOR",
    "RecordedDemandError",
    "RecordedDay",
    "demand_from_records",
    "recorded_days",
]

RECORDED_GENERATOR = "recorded"


class DemandLog(Protocol):
    """Where the demand recorded with the epochs is read (``app.usecases.SizingService``)."""

    def recorded_day(self, city: City, day: dt.date) -> list[str]:
        """The demand documents recorded with the epochs of the UTC days that overlap local ``day``."""
        ...


class RecordedDemandError(ValueError):
    """A recorded epoch cannot be read (the message names the day and the epoch)."""


@dataclass(frozen=True, slots=True)
class RecordedDay:
    """One local day of recorded demand."""

    date: dt.date
    demand: DemandSet


def demand_from_records(city: City, date: str | dt.date, records: Iterable[str]) -> DemandSet:
    """The riders of the recorded epochs ``records`` requested on local ``date`` as a ``DemandSet``.

    Riders are deduplicated by id (the first request time seen is kept); times are floored to whole
    seconds; riders requested on other local days are left out (a UTC day spans two local days). A rider
    whose origin or destination node the network does not know (the bundle was rebuilt since) is dropped
    and counted in ``params["unknown_nodes"]``.

    Raises
    ------
    RecordedDemandError
        A record that is not the JSON the service records.
    """
    day = dt.date.fromisoformat(date) if isinstance(date, str) else date
    tz = ZoneInfo(city.horizon.timezone)
    seen: dict[str, Request] = {}
    dropped: set[str] = set()
    epochs = rows = 0
    for i, text in enumerate(records):
        try:
            doc = json.loads(text)
            riders = list(doc["riders"])
        except (ValueError, KeyError, TypeError) as exc:
            raise RecordedDemandError(
                f"{city.name}, {day}: record {i} is not recorded demand ({exc!r})"
            ) from None
        epochs += 1
        for r in riders:
            rows += 1
            try:
                rid = str(r["id"])
                t = float(r["requested_at_s"])
                origin, dest = int(r["origin"]), int(r["destination"])
            except (ValueError, KeyError, TypeError) as exc:
                where = doc.get("epoch_id", i)
                raise RecordedDemandError(
                    f"{city.name}, {day}: epoch {where!r}: bad rider ({exc!r})"
                ) from None
            if rid in seen or rid in dropped:
                continue
            if not math.isfinite(t) or dt.datetime.fromtimestamp(t, tz=tz).date() != day:
                continue
            try:
                o, d = city.network.index_of(origin), city.network.index_of(dest)
            except SnapError:
                dropped.add(rid)
                continue
            seen[rid] = Request(rid, float(math.floor(t)), o, d)
    requests = sorted(seen.values(), key=lambda r: (r.time_s, r.id))
    return DemandSet(
        city=city.name,
        date=day.isoformat(),
        requests=tuple(requests),
        generator=RECORDED_GENERATOR,
        seed=None,
        params={"epochs": epochs, "rider_rows": rows, "unknown_nodes": len(dropped)},
    )


def recorded_days(
    source: DemandLog, city: City, before: dt.date, want: int, lookback_days: int
) -> list[RecordedDay]:
    """Up to ``want`` local days before ``before`` (newest first, within ``lookback_days``) on which the
    service recorded at least one request."""
    found: list[RecordedDay] = []
    for back in range(1, lookback_days + 1):
        day = before - dt.timedelta(days=back)
        records = source.recorded_day(city, day)
        if not records:
            continue
        demand = demand_from_records(city, day, records)
        if demand.requests:
            found.append(RecordedDay(day, demand))
            if len(found) == want:
                break
    return found
