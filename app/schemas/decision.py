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
from typing import Any, Literal, cast

import msgspec
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


class _Node(msgspec.Struct, forbid_unknown_fields=True, gc=False):
    """A location of the plain form: ``{"node": a JSON integer}`` and nothing else."""

    node: int


# The plain forms' fields are in the order of their keys, as the canonical JSON sorts them: msgspec encodes
# a decoded array back as the text ``body_hash`` writes for the model's dump of it but for the locations'
# ``"lat":null,"lon":null`` (``_canonical_text``).


class _PlainTaxi(msgspec.Struct, forbid_unknown_fields=True, gc=False):
    """A taxi of the plain form (``plain_taxis``): these four keys and no other, JSON types as written."""

    id: str
    instrumented: bool
    location: _Node
    status: Literal["vacant", "busy"]


class _PlainRider(msgspec.Struct, forbid_unknown_fields=True, gc=False):
    """A rider of the plain form (``plain_riders``)."""

    destination: _Node
    id: str
    origin: _Node
    requested_at: str


_TAXIS = msgspec.json.Decoder(list[_PlainTaxi])
_RIDERS = msgspec.json.Decoder(list[_PlainRider])
_ENCODER = msgspec.json.Encoder()
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
_INT64 = (-(2**63), 2**63 - 1)
if (
    set(TaxiIn.model_fields) != set(_PlainTaxi.__struct_fields__)
    or set(RiderIn.model_fields) != set(_PlainRider.__struct_fields__)
    or set(LocationIn.model_fields) != {"node", "lon", "lat"}
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


def _canonical_text(items: list[_PlainTaxi] | list[_PlainRider]) -> str:
    """The canonical JSON of plain taxis or riders: msgspec's encoding of their structs (fields in key
    order, compact, the ids' ``"`` and ``\\`` escaped as ``json.dumps`` escapes them, printable ASCII
    otherwise) with each location written as the model dumps it, ``{"lat":null,"lon":null,"node":...}``.
    ``{"node":`` opens a location and nothing else: inside a string its quotes would be escaped."""
    return _ENCODER.encode(items).decode().replace('{"node":', '{"lat":null,"lon":null,"node":')


def _in_int64(nodes: Sequence[int]) -> bool:
    return not nodes or (min(nodes) >= _INT64[0] and max(nodes) <= _INT64[1])


def _plain_ids(ids: Sequence[str]) -> bool:
    """Whether every id is printable ASCII text of 1..``ID_MAX_LEN`` characters (what ``Identifier``
    keeps)."""
    lengths = set(map(len, ids))
    if lengths and (min(lengths) < 1 or max(lengths) > ID_MAX_LEN):
        return False
    every_id = "".join(ids)  # no id is empty, so one look at them all
    return every_id.isascii() and not _CONTROL.search(every_id)


@dataclass(frozen=True, slots=True)
class PlainTaxis:
    """An epoch's taxis read by ``plain_taxis``: external node ids, and their part of the canonical JSON."""

    ids: tuple[str, ...]
    node_ids: tuple[int, ...]
    instrumented: tuple[bool, ...]
    vacant: tuple[bool, ...]
    canonical: str  # the JSON array ``body_hash`` writes for these taxis


def plain_taxis(raw: bytes | msgspec.Raw) -> PlainTaxis | None:
    """The JSON array ``taxis`` of an epoch body (its text, ``raw``) read without a model per taxi, when
    every item has the common form ``{"id": printable ASCII text of 1..128 characters, "location": {"node":
    a JSON integer in int64}, "instrumented": true or false, "status": "vacant" or "busy"}``: exactly what
    ``TaxiIn`` accepts and keeps unchanged in that form. ``None`` for anything else, including every item
    ``TaxiIn`` would refuse: the model then validates the taxis and says what is wrong
    (``app.api.bodies``). msgspec decodes the array into the form's structs (``_PlainTaxi``: the JSON types
    as written, no other key) in one pass; the checks of the values look at one field of every taxi at
    once."""
    try:
        items = _TAXIS.decode(raw)
    except (msgspec.MsgspecError, RecursionError):  # msgspec's nesting limit is Python's
        return None
    ids = tuple([t.id for t in items])
    nodes = tuple([t.location.node for t in items])
    if not _in_int64(nodes) or not _plain_ids(ids):
        return None
    instrumented = tuple([t.instrumented for t in items])
    vacant = tuple([t.status == "vacant" for t in items])
    return PlainTaxis(ids, nodes, instrumented, vacant, _canonical_text(items))


@dataclass(frozen=True, slots=True)
class PlainRiders:
    """An epoch's riders read by ``plain_riders``: external node ids, request times (POSIX seconds), and
    their part of the canonical JSON."""

    ids: tuple[str, ...]
    origins: tuple[int, ...]
    destinations: tuple[int, ...]
    requested_at_s: tuple[float, ...]
    canonical: str  # the JSON array ``body_hash`` writes for these riders


@functools.lru_cache(maxsize=8192)  # a waiting rider is posted again, with the same text, every epoch
def _plain_time_s(text: str) -> float | None:
    """POSIX seconds of a request time the model keeps as written (``_PLAIN_TIME``) and accepts (a real
    date whose UTC instant lies in the API's years), else ``None``."""
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


def plain_riders(raw: bytes | msgspec.Raw) -> PlainRiders | None:
    """The JSON array ``riders`` of an epoch body (its text, ``raw``) read without a model per rider, when
    every item has the common form ``{"id": printable ASCII text of 1..128 characters, "origin": {"node": a
    JSON integer in int64}, "destination": the same, "requested_at": "YYYY-MM-DDTHH:MM:SS+HH:MM"}`` (an
    offset other than +00:00 or -00:00, a real date whose UTC instant lies in the API's years): exactly
    what ``RiderIn`` accepts and keeps unchanged in that form. ``None`` for anything else, including every
    item ``RiderIn`` would refuse: the model then validates the riders and says what is wrong
    (``app.api.bodies``). Decoded as ``plain_taxis`` decodes the taxis (``_PlainRider``)."""
    try:
        items = _RIDERS.decode(raw)
    except (msgspec.MsgspecError, RecursionError):  # msgspec's nesting limit is Python's
        return None
    ids = tuple([r.id for r in items])
    origins = tuple([r.origin.node for r in items])
    destinations = tuple([r.destination.node for r in items])
    if not _in_int64(origins) or not _in_int64(destinations) or not _plain_ids(ids):
        return None
    times = tuple([_plain_time_s(r.requested_at) for r in items])
    if None in times:
        return None
    return PlainRiders(ids, origins, destinations, cast(tuple[float, ...], times), _canonical_text(items))


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
