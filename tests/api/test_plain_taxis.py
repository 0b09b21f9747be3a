"""An epoch body's taxis in their common form are read without a model per taxi (``plain_taxis``); every
other body goes through the model as before. Either way a post must come out exactly as the model alone
made it: the same resolved snapshot, the same canonical hash, or the same error (status, kind, detail and
fields). Checked here against the model-only path (validate the whole body, resolve, hash) on hand-picked and
on random bodies that mix every form a taxi can take, right or wrong."""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.adapters.city_registry import CityRegistry
from app.api.bodies import _json, _validate, epoch_post
from app.api.inputs import Limits, epoch_command, snapshot_of
from app.errors import ServiceError
from app.schemas.decision import EpochIn, body_hash, plain_taxis
from app.usecases import EpochCommand
from services.city import City
from tests.api.fakes import CITY, lonlat, node_id
from tests.api.payloads import epoch

LIMITS = Limits(max_riders=20, max_taxis=6, max_tasks=10)


def model_only(city: City, obj: Any, limits: Limits = LIMITS) -> EpochCommand:
    """The epoch path without ``plain_taxis`` and ``plain_riders``: the model validates the whole body."""
    body = _json(("application/json", json.dumps(obj).encode()))
    if isinstance(body, dict):
        for key, limit in (("riders", limits.max_riders), ("taxis", limits.max_taxis)):
            if isinstance(body.get(key), list) and len(body[key]) > limit:
                with pytest.raises(ServiceError):
                    epoch_post(("application/json", json.dumps(obj).encode()), limits)
                raise _Skip
    model = _validate(EpochIn, body)
    return EpochCommand(snapshot_of(city, model), body_hash(model), model.time.isoformat())


class _Skip(Exception):
    pass


def current(city: City, obj: Any, limits: Limits = LIMITS) -> EpochCommand:
    """The epoch path as the route runs it."""
    post = epoch_post(("application/json", json.dumps(obj).encode()), limits)
    return epoch_command(city, post.body, post.taxis, post.riders)


def outcome(run: Any, city: City, obj: Any) -> Any:
    try:
        return run(city, obj)
    except ServiceError as err:
        return (err.status, err.kind, err.detail, [(f.loc, f.msg) for f in err.fields])


def same(city: City, obj: Any) -> Any:
    """Both paths' outcome (asserted equal); a body of more items than the limits is refused by both."""
    try:
        before = outcome(model_only, city, obj)
    except _Skip:
        return None
    after = outcome(current, city, obj)
    assert after == before
    return after


def taxi(ident: str = "t0", node: Any = None, *, instrumented: Any = True, status: Any = "vacant") -> Any:
    return {
        "id": ident,
        "location": {"node": node_id(1, 1) if node is None else node},
        "instrumented": instrumented,
        "status": status,
    }


LON, LAT = lonlat(2, 3)
FORMS: list[Any] = [  # right and wrong taxis; ``{i}`` in an id is replaced by the item's position
    taxi("t{i}"),
    taxi("t{i}", node_id(4, 4), instrumented=False, status="busy"),
    taxi('q"\\/{i}'),
    taxi("x" * 126 + "{i}"),
    taxi("x" * 127 + "{i}"),
    taxi("x" * 128 + "{i}"),
    taxi("\U0001f695{i}"),
    taxi("", node_id(0, 0)),
    taxi("é{i}"),
    taxi("tab\t{i}"),
    taxi("del\x7f{i}"),
    taxi("t{i}", 1000.0),
    taxi("t{i}", 1000.5),
    taxi("t{i}", True),
    taxi("t{i}", "1000"),
    taxi("t{i}", 999),
    taxi("t{i}", 2**63 - 1),
    taxi("t{i}", -(2**63)),
    taxi("t{i}", 2**63),
    taxi("t{i}", instrumented=1),
    taxi("t{i}", instrumented=None),
    taxi("t{i}", status="VACANT"),
    taxi("t{i}", status=None),
    {"id": "t{i}", "location": {"lon": LON, "lat": LAT}, "instrumented": True, "status": "vacant"},
    {"id": "t{i}", "location": {"lon": 0.0, "lat": 0.0}, "instrumented": True, "status": "vacant"},
    {"id": "t{i}", "location": {"node": 1000, "lon": LON}, "instrumented": True, "status": "vacant"},
    {"id": "t{i}", "location": {"node": None}, "instrumented": True, "status": "vacant"},
    {
        "id": "t{i}",
        "location": {"lat": None, "node": node_id(2, 2), "lon": None},
        "instrumented": True,
        "status": "busy",
    },
    {
        "id": "t{i}",
        "location": {"node": node_id(2, 2), "lon": None},
        "instrumented": False,
        "status": "vacant",
    },
    {"id": "t{i}", "location": {"node": node_id(2, 2), "lon": "x"}, "instrumented": True, "status": "vacant"},
    {"id": "t{i}", "location": {}, "instrumented": True, "status": "vacant"},
    {"id": "t{i}", "location": [1000], "instrumented": True, "status": "vacant"},
    {"id": "t{i}", "location": {"node": 1000}, "instrumented": True},
    {"id": "t{i}", "location": {"node": 1000}, "instrumented": True, "status": "vacant", "x": 1},
    {"id": 7, "location": {"node": 1000}, "instrumented": True, "status": "vacant"},
    ["t{i}"],
    None,
]


def _text(value: Any) -> bytes:
    """A body member as its JSON text (what ``plain_taxis`` and ``plain_riders`` read)."""
    return json.dumps(value).encode()


def _instance(form: Any, i: int) -> Any:
    return json.loads(json.dumps(form).replace("{i}", str(i)))


@pytest.fixture(scope="module")
def city(registry: CityRegistry) -> City:
    return registry.get(CITY)


def test_common_taxis_take_the_plain_path_and_come_out_as_before(city: City) -> None:
    obj = epoch(taxis=[_instance(FORMS[k], i) for i, k in enumerate([0, 1, 2, 3, 4])])
    assert plain_taxis(_text(obj["taxis"])) is not None
    command = same(city, obj)
    assert isinstance(command, EpochCommand) and len(command.snapshot.taxis) == 5
    assert [t.vacant for t in command.snapshot.taxis] == [True, False, True, True, True]


@pytest.mark.parametrize("k", range(len(FORMS)))
def test_each_form_alone_and_beside_common_taxis(city: City, k: int) -> None:
    for taxis in ([_instance(FORMS[k], 0)], [_instance(FORMS[0], 0), _instance(FORMS[k], 1)]):
        same(city, epoch(taxis=taxis))


@pytest.mark.parametrize(
    "taxis",
    [
        None,
        {},
        "taxis",
        [],
        [taxi("t0"), taxi("t0")],  # duplicate ids
        [taxi(f"t{i}") for i in range(7)],  # more than the limit
        [taxi("t0"), taxi("t1", 999)],  # unknown node id at position 1
    ],
)
def test_whole_taxi_lists(city: City, taxis: Any) -> None:
    obj = epoch()
    if taxis is None:
        del obj["taxis"]
    else:
        obj["taxis"] = taxis
    same(city, obj)


def test_other_errors_with_common_taxis_are_the_models(city: City) -> None:
    bad_rider = epoch()
    bad_rider["riders"][0]["requested_at"] = "yesterday"
    bad_time = epoch()
    bad_time["time"] = "2026-13-01T00:00:00Z"
    extra = epoch() | {"note": 1}
    no_id = {k: v for k, v in epoch().items() if k != "epoch_id"}
    late = epoch()
    late["riders"][0]["requested_at"] = "2099-01-01T00:00:00Z"
    for obj in (bad_rider, bad_time, extra, no_id, late):
        assert plain_taxis(_text(obj["taxis"])) is not None
        result = same(city, obj)
        assert isinstance(result, tuple) and result[0] == 422


def draw(rng: random.Random, forms: list[Any], most: int, common: int = 8) -> list[Any]:
    """1..``most`` items of ``forms``, mostly their first five (the common ones, ``common`` times as likely
    as each other); one list in ten of two or more ends with a duplicate of its first item."""
    n = rng.randint(1, most)
    weights = [common if k < 5 else 1 for k in range(len(forms))]
    items = [_instance(rng.choices(forms, weights)[0], i) for i in range(n)]
    if rng.random() < 0.1 and n > 1:
        items[-1] = json.loads(json.dumps(items[0]))  # a duplicate
    return items


def test_random_bodies(city: City) -> None:
    rng = random.Random(20261123)
    plain = 0
    for _ in range(400):
        taxis = draw(rng, FORMS, 5)
        obj = epoch(taxis=taxis)
        plain += plain_taxis(_text(taxis)) is not None
        same(city, obj)
    assert plain > 100  # the plain path was exercised, not only the model's


def test_the_canonical_taxis_are_the_models_dump() -> None:
    """The hash of a body read with ``plain_taxis`` is the hash of the whole model, node ids at the ends
    of int64 and ids that JSON escapes included (no city involved)."""
    taxis = [
        taxi('a"b\\c/d'),
        taxi("x" * 128, 2**63 - 1, instrumented=False, status="busy"),
        taxi("n", -(2**63)),
        taxi('{"node":1}'),  # the text that opens a location, inside an id
    ]
    obj = epoch(taxis=taxis)
    plain = plain_taxis(_text(taxis))
    assert plain is not None
    rest = EpochIn.model_validate({**obj, "taxis": []})
    assert body_hash(rest, plain) == body_hash(EpochIn.model_validate(obj))


def test_lon_lat_positions_snapped_together_are_the_nodes_one_at_a_time() -> None:
    """``snap_all`` snaps every lon/lat of an epoch in one call: each position gets the node and distance
    ``Network.snap`` gives it alone; a position off the network is still refused naming its field."""
    from app.api.inputs import node_of, snap_all
    from app.errors import InvalidInput
    from app.schemas.common import LocationIn
    from services.citydata import load_city

    city = load_city(Path(__file__).resolve().parents[2] / "app" / "data" / "cities" / "chengdu")
    net = city.network
    rng = np.random.default_rng(4)
    pick = rng.integers(net.n_nodes, size=300)
    locs = [
        LocationIn(lon=float(net.lon[v]) + d, lat=float(net.lat[v]) - d)
        for v, d in zip(pick, rng.uniform(-3e-4, 3e-4, 300), strict=True)
    ]
    locs.append(LocationIn(node=int(net.node_ids[7])))
    far = LocationIn(lon=104.5, lat=30.9)
    snapped = snap_all(city, [*locs, far])
    assert len(snapped) == 301
    for loc in locs[:-1]:
        assert node_of(city, loc, "x", snapped) == net.snap(loc.lon, loc.lat, city.params.snap_limit_m)[0]  # type: ignore[arg-type]
    assert node_of(city, locs[-1], "x", snapped) == 7
    with pytest.raises(InvalidInput, match="farther than"):
        node_of(city, far, "taxis[3].location", snapped)


def _model_only_text(city: City, data: bytes) -> EpochCommand:
    """``model_only`` on a body's text as it is (JSON that ``json.dumps`` would not write)."""
    body = _json(("application/json", data))
    model = _validate(EpochIn, body)
    return EpochCommand(snapshot_of(city, model), body_hash(model), model.time.isoformat())


def _current_text(city: City, data: bytes) -> EpochCommand:
    post = epoch_post(("application/json", data), LIMITS)
    return epoch_command(city, post.body, post.taxis, post.riders)


def test_bodies_only_their_text_can_show_come_out_as_the_models(city: City) -> None:
    """Duplicate members (the last one counts), NaN (only pydantic-core reads it), nesting deeper than
    msgspec's limit, bodies that are not one object, spacing, and taxis or riders the plain path cannot
    read beside those it can."""
    body = json.dumps(epoch(taxis=[taxi("t0"), taxi("t1", node_id(4, 4))]))
    head, tail = body[:-1], body[-1]
    first_taxi = json.dumps([taxi("x0")])
    nan_rider = json.dumps(epoch()).replace('"requested_at": "', '"requested_at": NaN, "r": "', 1)
    texts = [
        body,
        f"  \n{body}\t ",
        f'{head}, "taxis": {first_taxi}{tail}',  # a second taxis member: the last one counts
        f'{{"taxis": {first_taxi}, {body[1:]}',  # the first of two taxis members
        f'{head}, "epoch_id": "again"{tail}',
        nan_rider,
        body.replace('"taxis": [', '"taxis": [NaN, ', 1),
        f'{head}, "deep": {"[" * 5_000}{"]" * 5_000}{tail}',
        "[]",
        '"epoch"',
        "5",
        "null",
        body + " {}",
        body[:-2],
        "",
    ]
    solved = []
    for text in texts:
        data = text.encode()
        expected, got = outcome(_model_only_text, city, data), outcome(_current_text, city, data)
        assert got == expected, text[:200]
        solved.append(isinstance(got, EpochCommand))
    assert solved[:5] == [True] * 5 and not any(solved[5:])
    assert [t.id for t in outcome(_current_text, city, texts[2].encode()).snapshot.taxis] == ["x0"]
