"""Models of the epoch route (``app.api.writes``): the posted epoch, its canonical hash, and the decision
as the response document renders it (stored with the commit and returned verbatim to replays)."""

from __future__ import annotations

import datetime as dt
import functools
import hashlib
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from json.encoder import encode_basestring_ascii
from operator import itemgetter
from typing import Any, Literal, cast

from pydantic import Field, StrictBool

from app.schemas.common import (
    ID_MAX_LEN,
    Identifier,
    LocationIn,
    RequestModel,
    ResponseModel,
    Rfc3339,
    TimedRequest,
)
from app.schemas.tasks import TaskOut
from app.usecases import EpochResult
from app.usecases.epoch_record import epoch_doc
from services.rfc3339 import MAX_YEAR, MIN_YEAR

__all__ = [
    "RiderIn",
    "TaxiIn",
    "EpochIn",
    "PlainTaxis",
    "plain_taxis",
    "PlainRiders",
    "plain_riders",
    "body_hash",
    "RiderMatchOut",
    "TaskAssignmentOut",
    "EpochOut",
]


class RiderIn(TimedRequest):
    """A waiting rider."""

    id: Identifier
    origin: LocationIn
    destination: LocationIn
    requested_at: Rfc3339


class TaxiIn(RequestModel):
    """A taxi's position and state at the epoch."""

    id: Identifier
    location: LocationIn
    instrumented: StrictBool
    status: Literal["vacant", "busy"]


class EpochIn(TimedRequest):
    """One decision epoch posted by the platform."""

    epoch_id: Identifier
    time: Rfc3339
    riders: list[RiderIn]
    taxis: list[TaxiIn]


_TAXI_FIELDS = ("id", "location", "instrumented", "status")
_RIDER_FIELDS = ("id", "origin", "destination", "requested_at")
_TAXI_KEYS = frozenset(_TAXI_FIELDS)
_RIDER_KEYS = frozenset(_RIDER_FIELDS)
_NODE = itemgetter("node")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
_INT64 = (-(2**63), 2**63 - 1)
_LOCATION_KEYS = frozenset({"node", "lon", "lat"})
if (frozenset(TaxiIn.model_fields), frozenset(LocationIn.model_fields), frozenset(RiderIn.model_fields)) != (
    _TAXI_KEYS,
    _LOCATION_KEYS,
    _RIDER_KEYS,
):
    # plain_taxis and plain_riders write exactly these fields' canonical JSON
    raise RuntimeError(
        "plain_taxis and plain_riders read the models as they are: change them with the models"
    )
# a time the model keeps as it is written (its JSON dump gives the same text): seconds, no fraction, an
# offset other than +00:00 and -00:00 (which the dump writes as Z), a year within the API's range
_PLAIN_TIME = re.compile(
    r"(19[7-9][0-9]|2[0-9]{3})-(0[1-9]|1[0-2])-(0[1-9]|[12][0-9]|3[01])T([01][0-9]|2[0-3]):[0-5][0-9]:[0-5][0-9]"
    r"[+-](?!00:00)([01][0-9]|2[0-3]):[0-5][0-9]"
)


def _columns(value: object, fields: tuple[str, ...]) -> tuple[tuple[Any, ...], ...] | None:
    """The values of ``fields`` of every item of ``value``, field by field, when ``value`` is a list of
    objects that each have exactly these keys, else ``None`` (a list with no items: one empty column per
    field)."""
    if type(value) is not list:
        return None
    if not value:
        return tuple(() for _ in fields)
    if set(map(type, value)) != {dict} or set(map(len, value)) != {len(fields)}:
        return None
    try:  # as many keys as fields, and every field there: exactly these keys
        return tuple(zip(*map(itemgetter(*fields), value), strict=True))
    except KeyError:
        return None


def _plain_nodes(locations: tuple[Any, ...]) -> tuple[int, ...] | None:
    """The node ids of locations that all have the form ``{"node": a JSON integer in int64}``, else
    ``None``."""
    if not locations:
        return ()
    if set(map(type, locations)) != {dict} or set(map(len, locations)) != {1}:
        return None
    try:
        nodes = tuple(map(_NODE, locations))
    except KeyError:
        return None
    lo, hi = _INT64
    if set(map(type, nodes)) != {int} or min(nodes) < lo or max(nodes) > hi:
        return None
    return nodes


def _plain_ids(ids: Sequence[object]) -> bool:
    """Whether every id is printable ASCII text of 1..``ID_MAX_LEN`` characters (what ``Identifier``
    keeps)."""
    if not set(map(type, ids)) <= {str}:
        return False
    texts = cast(Sequence[str], ids)
    lengths = set(map(len, texts))
    if lengths and (min(lengths) < 1 or max(lengths) > ID_MAX_LEN):
        return False
    every_id = "".join(texts)  # no id is empty, so one look at them all
    return every_id.isascii() and not _CONTROL.search(every_id)


@dataclass(frozen=True, slots=True)
class PlainTaxis:
    """An epoch's taxis read by ``plain_taxis``: external node ids, and their part of the canonical JSON."""

    ids: tuple[str, ...]
    node_ids: tuple[int, ...]
    instrumented: tuple[bool, ...]
    vacant: tuple[bool, ...]
    canonical: str  # the JSON array ``body_hash`` writes for these taxis


def plain_taxis(value: object) -> PlainTaxis | None:
    """The parsed JSON ``taxis`` of an epoch body read without a model per taxi, when every item has the
    common form ``{"id": printable ASCII text of 1..128 characters, "location": {"node": a JSON integer in
    int64}, "instrumented": true or false, "status": "vacant" or "busy"}``: exactly what ``TaxiIn`` accepts
    and keeps unchanged in that form. ``None`` for anything else, including every item ``TaxiIn`` would
    refuse: the model then validates the taxis and says what is wrong (``app.api.bodies``). Each check
    looks at one field of every taxi at once (``_columns``)."""
    columns = _columns(value, _TAXI_FIELDS)
    if columns is None:
        return None
    ids, locations, instrumented, status = columns
    nodes = _plain_nodes(locations)
    if (
        nodes is None
        or not set(map(type, instrumented)) <= {bool}
        or not set(map(type, status)) <= {str}
        or not set(status) <= {"vacant", "busy"}
        or not _plain_ids(ids)
    ):
        return None
    canonical = ",".join(
        [
            f'{{"id":{ident},"instrumented":{"true" if instr else "false"},'
            f'"location":{{"lat":null,"lon":null,"node":{node}}},"status":"{state}"}}'
            for ident, instr, node, state in zip(
                map(encode_basestring_ascii, ids), instrumented, nodes, status, strict=True
            )
        ]
    )
    return PlainTaxis(ids, nodes, instrumented, tuple(map("vacant".__eq__, status)), f"[{canonical}]")


@dataclass(frozen=True, slots=True)
class PlainRiders:
    """An epoch's riders read by ``plain_riders``: external node ids, request times (POSIX seconds), and
    their part of the canonical JSON."""

    ids: tuple[str, ...]
    origins: tuple[int, ...]
    destinations: tuple[int, ...]
    requested_at_s: tuple[float, ...]
    canonical: str  # the JSON array ``body_hash`` writes for these riders


def _plain_time_s(text: object) -> float | None:
    """POSIX seconds of a request time the model keeps as written (``_PLAIN_TIME``) and accepts (a real
    date whose UTC instant lies in the API's years), else ``None``."""
    return _plain_text_s(text) if type(text) is str else None


@functools.lru_cache(maxsize=8192)  # a waiting rider is posted again, with the same text, every epoch
def _plain_text_s(text: str) -> float | None:
    if not _PLAIN_TIME.fullmatch(text):
        return None
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:  # no such day (2026-02-30)
        return None
    year = int(text[:4])
    # offsets are under a day: only an instant in the first or the last year can leave the range in UTC
    if year in (MIN_YEAR, MAX_YEAR) and not MIN_YEAR <= when.astimezone(dt.UTC).year <= MAX_YEAR:
        return None
    return when.timestamp()


def plain_riders(value: object) -> PlainRiders | None:
    """The parsed JSON ``riders`` of an epoch body read without a model per rider, when every item has the
    common form ``{"id": printable ASCII text of 1..128 characters, "origin": {"node": a JSON integer in
    int64}, "destination": the same, "requested_at": "YYYY-MM-DDTHH:MM:SS+HH:MM"}`` (an offset other than
    +00:00 or -00:00, a real date whose UTC instant lies in the API's years): exactly what ``RiderIn``
    accepts and keeps unchanged in that form. ``None`` for anything else, including every item ``RiderIn``
    would refuse: the model then validates the riders and says what is wrong (``app.api.bodies``). Each
    check looks at one field of every rider at once (``_columns``)."""
    columns = _columns(value, _RIDER_FIELDS)
    if columns is None:
        return None
    ids, origin_locs, destination_locs, texts = columns
    origins, destinations = _plain_nodes(origin_locs), _plain_nodes(destination_locs)
    if origins is None or destinations is None or not _plain_ids(ids):
        return None
    times = tuple(map(_plain_time_s, texts))
    if None in times:
        return None
    canonical = ",".join(
        [
            f'{{"destination":{{"lat":null,"lon":null,"node":{destination}}},"id":{ident},'
            f'"origin":{{"lat":null,"lon":null,"node":{origin}}},"requested_at":"{text}"}}'
            for ident, origin, destination, text in zip(
                map(encode_basestring_ascii, ids), origins, destinations, texts, strict=True
            )
        ]
    )
    return PlainRiders(ids, origins, destinations, cast(tuple[float, ...], times), f"[{canonical}]")


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def body_hash(body: EpochIn, taxis: PlainTaxis | None = None, riders: PlainRiders | None = None) -> str:
    """sha256 of the canonical JSON of a validated epoch body: the model dumped in JSON mode, keys sorted,
    no spaces. Every committed epoch stores it and a replay must match it, so this never changes.

    With ``taxis`` (``riders``), the body's taxis (riders) read by ``plain_taxis`` (``plain_riders``) and
    ``body`` validated without them, their part is their ``canonical``: the same text the model's dump of
    them gives (tests/api/test_plain_taxis.py, test_plain_riders.py)."""
    dump = body.model_dump(mode="json")
    if taxis is None and riders is None:
        return hashlib.sha256(_canonical(dump).encode()).hexdigest()
    plain = {
        "taxis": None if taxis is None else taxis.canonical,
        "riders": None if riders is None else riders.canonical,
    }
    canonical = (
        "{"
        + ",".join(f"{_canonical(key)}:{plain.get(key) or _canonical(dump[key])}" for key in sorted(dump))
        + "}"
    )
    return hashlib.sha256(canonical.encode()).hexdigest()


class RiderMatchOut(ResponseModel):
    """A taxi sent to a rider (Step 1: instrumented, Step 2: not)."""

    step: Literal[1, 2]
    taxi_id: str
    rider_id: str
    pickup_m: float
    wait_s: float
    trip_m: float
    trip_time_s: float = Field(description="Travel time from the pickup to the dropoff.")
    sensing_gain: float
    path: list[int] = Field(description="External node ids from the taxi via the pickup to the dropoff.")
    cells: list[tuple[int, int]] = Field(description="G-route of the path, [col, row] in order.")


class TaskAssignmentOut(ResponseModel):
    """A vacant instrumented taxi sent along a sensing route to a POI (Step 3)."""

    taxi_id: str
    task_id: str
    path: list[int]
    cells: list[tuple[int, int]]
    length_m: float
    travel_time_s: float
    sensing_gain: float
    efficiency: float = Field(description="sensing_gain / travel_time_s (Eq. 12).")
    cost_cny: float
    kappa: float = Field(description="The trade-off kappa the route was planned with (Algorithm 1).")


class EpochOut(ResponseModel):
    """What was decided for one epoch."""

    epoch_id: str
    time: str
    rider_matches: list[RiderMatchOut]
    task_assignments: list[TaskAssignmentOut]
    tasks_completed: list[TaskOut]
    unmatched_rider_ids: list[str]
    expired_rider_ids: list[str]
    stats: dict[str, float | int | str] = Field(
        description="Matches per step, interval label, solve time, Gamma and other diagnostics."
    )

    @classmethod
    def of(cls, result: EpochResult) -> EpochOut:
        """Render a decided epoch with external node ids and local times (validated)."""
        return cls.model_validate(epoch_doc(result))
