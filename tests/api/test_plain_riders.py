"""An epoch body's riders in their common form are read without a model per rider (``plain_riders``); every
other body goes through the model as before. Either way a post must come out exactly as the model alone
made it: the same resolved snapshot, the same canonical hash, or the same error (status, kind, detail and
fields). Checked against the whole model (``tests.api.test_plain_taxis.model_only``) on hand-picked and on
random bodies that mix every form a rider can take, right or wrong, beside common and other taxis."""

from __future__ import annotations

import random
from typing import Any

import pytest

from app.schemas.decision import EpochIn, body_hash, plain_riders, plain_taxis
from app.usecases import EpochCommand
from services.city import City
from tests.api.fakes import lonlat, node_id
from tests.api.payloads import epoch
from tests.api.test_plain_taxis import FORMS as TAXI_FORMS
from tests.api.test_plain_taxis import _instance, _text, city, draw, same

__all__ = ["city"]  # the module's fixture, shared


def rider(
    ident: str = "r{i}",
    origin: Any = None,
    destination: Any = None,
    requested_at: Any = "2026-11-23T07:59:30+08:00",
) -> Any:
    return {
        "id": ident,
        "origin": {"node": node_id(0, 0)} if origin is None else origin,
        "destination": {"node": node_id(4, 4)} if destination is None else destination,
        "requested_at": requested_at,
    }


LON, LAT = lonlat(2, 3)
FORMS: list[Any] = [  # right and wrong riders; ``{i}`` in an id is replaced by the item's position
    rider(),
    rider(origin={"node": node_id(2, 1)}, requested_at="2026-11-23T00:50:00+01:00"),
    rider('q"\\/{i}', requested_at="2026-11-22T19:00:00-05:00"),
    rider("x" * 126 + "{i}", requested_at="2026-11-23T05:29:59+05:30"),
    rider("x" * 127 + "{i}"),
    rider("x" * 128 + "{i}"),
    rider("\U0001f695{i}"),
    rider(""),
    rider("tab\t{i}"),
    rider("del\x7f{i}"),
    rider(origin={"node": 1000.0}),
    rider(destination={"node": 1000.5}),
    rider(origin={"node": True}),
    rider(origin={"node": "1000"}),
    rider(origin={"node": 999}),
    rider(destination={"node": 2**63}),
    rider(origin={"lon": LON, "lat": LAT}),
    rider(destination={"lon": 0.0, "lat": 0.0}),
    rider(origin={"node": 1000, "lon": LON}),
    rider(origin={"node": None}),
    rider(origin={"lat": None, "node": node_id(1, 2), "lon": None}),
    rider(destination={"node": node_id(3, 3), "lon": None}),
    rider(origin={"node": node_id(1, 2), "lat": 0}),
    rider(destination={}),
    rider(origin=[1000]),
    rider(requested_at="2026-11-23T07:59:30Z"),
    rider(requested_at="2026-11-23T07:59:30+00:00"),
    rider(requested_at="2026-11-23T07:59:30-00:00"),
    rider(requested_at="2026-11-23T07:59:30.250+08:00"),
    rider(requested_at="2026-11-23t07:59:30+08:00"),
    rider(requested_at="2026-11-23 07:59:30+08:00"),
    rider(requested_at="2026-11-23T07:59+08:00"),
    rider(requested_at="2026-11-23T07:59:30"),
    rider(requested_at="2026-02-30T07:59:30+08:00"),
    rider(requested_at="2026-11-23T24:00:00+08:00"),
    rider(requested_at="2026-11-23T08:00:01+08:00"),  # after the epoch's time
    rider(requested_at="1970-01-01T00:30:00+01:00"),  # 1969 in UTC
    rider(requested_at="1970-01-01T00:30:00-01:00"),
    rider(requested_at="1969-12-31T23:00:00+08:00"),
    rider(requested_at="2026-11-23T07:59:30+24:00"),
    rider(requested_at=1795391970),
    rider(requested_at=None),
    {"id": "r{i}", "origin": {"node": 1000}, "destination": {"node": 1001}},
    {**rider(), "x": 1},
    {**rider(), "id": 7},
    ["r{i}"],
    None,
]


def test_common_riders_take_the_plain_path_and_come_out_as_before(city: City) -> None:
    obj = epoch(riders=[_instance(FORMS[k], i) for i, k in enumerate([0, 1, 2, 3, 4])])
    assert plain_riders(_text(obj["riders"])) is not None and plain_taxis(_text(obj["taxis"])) is not None
    command = same(city, obj)
    assert isinstance(command, EpochCommand) and len(command.snapshot.riders) == 5
    assert [r.requested_at_s for r in command.snapshot.riders][:2] == [1795391970.0, 1795391400.0]


@pytest.mark.parametrize("k", range(len(FORMS)))
def test_each_form_alone_and_beside_common_riders(city: City, k: int) -> None:
    for riders in ([_instance(FORMS[k], 0)], [_instance(FORMS[0], 0), _instance(FORMS[k], 1)]):
        same(city, epoch(riders=riders))


@pytest.mark.parametrize(
    "riders",
    [None, {}, "riders", [], [rider("r0"), rider("r0")], [rider(f"r{i}") for i in range(21)]],
)
def test_whole_rider_lists(city: City, riders: Any) -> None:
    obj = epoch(riders=[])
    if riders is None:
        del obj["riders"]
    else:
        obj["riders"] = riders
    same(city, obj)


def test_random_bodies(city: City) -> None:
    rng = random.Random(20261127)
    plain = 0
    for _ in range(400):
        riders, taxis = draw(rng, FORMS, 5, common=12), draw(rng, TAXI_FORMS, 3)
        obj = epoch(riders=riders, taxis=taxis)
        if rng.random() < 0.05:
            obj["time"] = "2026-11-23T08:00:00"  # another error beside the riders
        plain += plain_riders(_text(riders)) is not None
        same(city, obj)
    assert plain > 100  # the plain path was exercised, not only the model's


def test_the_canonical_riders_are_the_models_dump() -> None:
    """The hash of a body read with ``plain_riders`` (and ``plain_taxis``) is the hash of the whole model:
    node ids at the ends of int64, ids that JSON escapes and offsets either side included."""
    riders = [
        rider('a"b\\c/d', requested_at="2026-11-22T19:00:00-05:00"),
        rider("x" * 128, {"node": 2**63 - 1}, {"node": -(2**63)}, "2999-12-31T23:59:59+01:00"),
        rider("n", requested_at="1970-01-01T08:00:00+08:00"),
    ]
    obj = epoch(riders=riders)
    plain = plain_riders(_text(riders))
    assert plain is not None and plain.requested_at_s[2] == 0.0
    whole = body_hash(EpochIn.model_validate(obj))
    assert body_hash(EpochIn.model_validate({**obj, "riders": []}), riders=plain) == whole
    taxis = plain_taxis(_text(obj["taxis"]))
    assert taxis is not None
    assert body_hash(EpochIn.model_validate({**obj, "riders": [], "taxis": []}), taxis, plain) == whole
