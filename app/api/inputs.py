"""Requests to the core's types: ids checked, locations resolved against the city, interval queries parsed
(a body's sizes are checked before it is validated, in ``app.api.bodies``). Every refusal is a 422 naming
the offending field, raised before the store is touched."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from app.errors import InvalidInput
from app.schemas.common import LABEL_PATTERN, RFC3339_PATTERN, LocationIn
from app.schemas.decision import EpochIn, PlainRiders, PlainTaxis, body_hash
from app.schemas.tasks import TaskIn
from app.settings import Settings
from app.usecases import EpochCommand
from app.usecases.epoch_record import node_index
from services.city import City
from services.model import IntervalKey, Rider, RiderId, Snapshot, Task, TaskId, Taxi, TaxiId
from services.network.network import SnapError

__all__ = [
    "Limits",
    "node_of",
    "snapshot_of",
    "epoch_command",
    "tasks_of",
    "interval_of",
    "INTERVAL_PATTERN",
]

INTERVAL_PATTERN = f"(?:{LABEL_PATTERN})|(?:{RFC3339_PATTERN})"
_INTERVAL = re.compile(INTERVAL_PATTERN)


@dataclass(frozen=True, slots=True)
class Limits:
    """Items per request (``SD_MAX_RIDERS``, ``SD_MAX_TAXIS``, ``SD_MAX_TASKS``)."""

    max_riders: int = 2000
    max_taxis: int = 5000
    max_tasks: int = 1000

    @classmethod
    def from_settings(cls, settings: Settings) -> Limits:
        """The limits the settings set."""
        return cls(settings.limits.max_riders, settings.limits.max_taxis, settings.limits.max_tasks)


Snapped = dict[int, tuple[int, float]]
"""Locations given as lon/lat, snapped beforehand: ``id(location)`` -> (nearest node, its distance in m)."""


def node_of(city: City, loc: LocationIn, where: str, snapped: Snapped | None = None) -> int:
    """Node index of a location; 422 naming ``where`` when it is unknown or off the network. A lon/lat found
    in ``snapped`` (``snap_all``) is not snapped again."""
    if loc.node is not None:
        try:
            return city.network.index_of(loc.node)
        except SnapError:
            raise InvalidInput.at(f"{where}.node", f"unknown node id {loc.node}") from None
    assert loc.lon is not None and loc.lat is not None
    limit = city.params.snap_limit_m
    try:
        node, dist = (snapped or {}).get(id(loc)) or city.network.snap(loc.lon, loc.lat, limit)
        if not dist <= limit:
            raise SnapError(where)
    except SnapError:
        raise InvalidInput.at(
            where, f"({loc.lon}, {loc.lat}) is farther than {limit:.0f} m from every node"
        ) from None
    return node


def snap_all(city: City, locations: Sequence[LocationIn]) -> Snapped:
    """Every lon/lat among ``locations`` snapped to its nearest node in one call (one projection and one
    k-d tree query for all: 5,800 positions one at a time take ~25 times as long). Empty when one of them
    is not a position at all: ``node_of`` then names it."""
    given = [loc for loc in locations if loc.node is None and loc.lon is not None and loc.lat is not None]
    if not given:
        return {}
    try:
        xy = np.array([(loc.lon, loc.lat) for loc in given], dtype=np.float64)
        nodes, dist = city.network.snap_many(xy[:, 0], xy[:, 1], float("inf"))
    except SnapError:
        return {}
    return {
        id(loc): (int(n), float(d)) for loc, n, d in zip(given, nodes.tolist(), dist.tolist(), strict=True)
    }


def _unique(ids: Sequence[str], where: str) -> None:
    """422 naming the first id that repeats an earlier one."""
    if len(set(ids)) == len(ids):
        return
    seen: set[str] = set()
    for i, ident in enumerate(ids):
        if ident in seen:
            raise InvalidInput.at(f"{where}[{i}].id", f"duplicate id {ident!r}")
        seen.add(ident)


def _riders(city: City, body: EpochIn, time_s: float, snapped: Snapped) -> list[Rider]:
    """The body's riders (validated by the model) resolved, in order, each checked as it comes."""
    riders: list[Rider] = []
    for i, r in enumerate(body.riders):
        requested_s = r.requested_at.timestamp()
        if requested_s > time_s:
            raise InvalidInput.at(f"riders[{i}].requested_at", "is later than the epoch time")
        riders.append(
            Rider(
                id=RiderId(r.id),
                origin=node_of(city, r.origin, f"riders[{i}].origin", snapped),
                destination=node_of(city, r.destination, f"riders[{i}].destination", snapped),
                requested_at_s=requested_s,
            )
        )
    return riders


def _plain_riders(city: City, plain: PlainRiders, time_s: float) -> list[Rider]:
    """Riders read by ``plain_riders``, checked in the same order with the same errors as ``_riders``."""
    index_of = city.network.index_of
    if not plain.ids:
        return []
    if max(plain.requested_at_s) <= time_s:
        at = node_index(city).__getitem__  # the node ids are ints in int64 (``plain_riders``)
        try:  # the common case, every node known: no error to name
            origins, destinations = list(map(at, plain.origins)), list(map(at, plain.destinations))
        except KeyError:
            pass
        else:
            ids = cast(tuple[RiderId, ...], plain.ids)
            return list(map(Rider, ids, origins, destinations, plain.requested_at_s))
    riders: list[Rider] = []
    for i, (ident, origin, destination, requested_s) in enumerate(
        zip(plain.ids, plain.origins, plain.destinations, plain.requested_at_s, strict=True)
    ):
        if requested_s > time_s:
            raise InvalidInput.at(f"riders[{i}].requested_at", "is later than the epoch time")
        nodes = []
        for node_id, end in ((origin, "origin"), (destination, "destination")):
            try:
                nodes.append(index_of(node_id))
            except SnapError:
                node_of(city, LocationIn(node=node_id), f"riders[{i}].{end}")  # raises, naming the field
        riders.append(Rider(RiderId(ident), nodes[0], nodes[1], requested_s))
    return riders


def snapshot_of(
    city: City,
    body: EpochIn,
    plain: PlainTaxis | None = None,
    plain_riders: PlainRiders | None = None,
) -> Snapshot:
    """The epoch resolved to node indices (unique ids, request times and locations checked). With
    ``plain`` (``plain_riders``), the body's taxis (riders) read by ``plain_taxis`` (``plain_riders``) and
    ``body`` validated without them, the taxis (riders) are those, checked in the same order with the same
    errors."""
    taxi_ids = [t.id for t in body.taxis] if plain is None else plain.ids
    rider_ids = [r.id for r in body.riders] if plain_riders is None else plain_riders.ids
    _unique(rider_ids, "riders")
    _unique(taxi_ids, "taxis")
    time_s = body.time.timestamp()
    snapped = snap_all(
        city,
        [
            *(r.origin for r in body.riders),
            *(r.destination for r in body.riders),
            *(t.location for t in body.taxis),
        ],
    )
    if plain_riders is None:
        riders = _riders(city, body, time_s, snapped)
    else:
        riders = _plain_riders(city, plain_riders, time_s)
    index_of = city.network.index_of
    taxis: list[Taxi] = []
    if plain is not None:
        try:  # the common case, every node known: no error to name (node ids are ints in int64)
            nodes = list(map(node_index(city).__getitem__, plain.node_ids))
        except KeyError:
            for i, node_id in enumerate(plain.node_ids):
                try:
                    index_of(node_id)
                except SnapError:
                    node_of(city, LocationIn(node=node_id), f"taxis[{i}].location")  # raises, naming it
            raise
        ids = cast(tuple[TaxiId, ...], plain.ids)
        taxis = list(map(Taxi, ids, nodes, plain.instrumented, plain.vacant))
    for i, t in enumerate(body.taxis):
        loc = t.location
        try:  # the common case, a known node id, without building the field's name
            node = index_of(loc.node) if loc.node is not None else node_of(city, loc, "", snapped)
        except (SnapError, InvalidInput):
            node = node_of(city, loc, f"taxis[{i}].location", snapped)  # raises, naming the field
        taxis.append(Taxi(TaxiId(t.id), node, t.instrumented, t.status == "vacant"))
    return Snapshot(epoch_id=body.epoch_id, time_s=time_s, riders=tuple(riders), taxis=tuple(taxis))


def epoch_command(
    city: City,
    body: EpochIn,
    plain: PlainTaxis | None = None,
    plain_riders: PlainRiders | None = None,
) -> EpochCommand:
    """The use case's input for an epoch post: the snapshot, the body's canonical hash and the posted time
    (``plain``, ``plain_riders``: the body's taxis and riders as ``plain_taxis`` and ``plain_riders`` read
    them, ``body`` validated without them)."""
    return EpochCommand(
        snapshot_of(city, body, plain, plain_riders),
        body_hash(body, plain, plain_riders),
        body.time.isoformat(),
    )


def tasks_of(city: City, tasks: Sequence[TaskIn]) -> list[Task]:
    """Tasks to register, resolved to node indices (a lon/lat registration keeps its position)."""
    _unique([t.id for t in tasks], "")
    out: list[Task] = []
    for i, t in enumerate(tasks):
        node = node_of(city, t.location, f"[{i}].location")
        where = None if t.location.lon is None or t.location.lat is None else (t.location.lon, t.location.lat)
        out.append(
            Task(id=TaskId(t.id), node=node, scheduled_at_s=t.scheduled_at.timestamp(), location=where)
        )
    return out


def interval_of(city: City, text: str) -> IntervalKey:
    """The interval of ``?interval=``: a label (``YYYY-MM-DDTHH:MM``) or an RFC 3339 time inside it, in the
    years 1970..2999 (``INTERVAL_PATTERN``: checked before any date arithmetic, which could overflow)."""
    if not _INTERVAL.match(text):
        raise InvalidInput.at(
            "interval", "give a label YYYY-MM-DDTHH:MM or an RFC 3339 time with an offset, years 1970..2999"
        )
    try:
        return city.horizon.parse_interval(text)
    except (ValueError, OverflowError) as exc:
        raise InvalidInput.at("interval", str(exc)) from None
