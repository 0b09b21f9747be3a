"""The service as a careless or hostile client tries it:

1. an epoch dated far ahead cannot block the city (a 422; an admin rewind or reset undoes a block);
2. a 1 MiB body of empty items cannot amplify into a huge error (the field list is capped, the body refused
   before item validation);
3. extreme UTC offsets are a 422, not an overflow;
6. a commit the store applied but whose reply was lost and re-sent is reported as committed, not replayed;
7. a 405 carries ``Allow``; the OpenAPI is as strict as the server; ``/readyz`` names no Redis host.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.adapters import MemoryStore, RedisStore
from app.adapters.city_registry import CityRegistry
from app.api.handlers import MAX_FIELDS
from app.bootstrap import create_app
from app.ports import CommitResult, EpochCommit, Store
from tests.api import payloads
from tests.api.conftest import CITY, TOKENS, auth, fingerprint
from tests.api.fakes import T0, FakeDecide, node_id, rfc

EPOCHS = f"/v1/cities/{CITY}/epochs"
TASKS = f"/v1/cities/{CITY}/tasks"
ADMIN = "tok-admin-0000001"
READ = "tok-read-00000001"


@dataclass
class Clock:
    now_s: float

    def __call__(self) -> float:
        return self.now_s


MakeApp = Callable[..., TestClient]


@pytest.fixture
def make_app(registry: CityRegistry) -> MakeApp:
    """A client over ``create_app`` with the tokens, an admin token, a settable clock (T0 + 1 h)."""

    def make(store: Store | None = None, clock: Clock | None = None, **overrides: Any) -> TestClient:
        from app.settings import Settings

        settings = Settings.model_validate({"tokens": TOKENS | {ADMIN: ["admin"]}} | overrides)
        app = create_app(
            settings,
            registry=registry,
            store=store or MemoryStore(),
            decide=FakeDecide(),
            clock=clock or Clock(T0.timestamp() + 3600),
        )
        return TestClient(app)

    return make


def _error(r: Any, status: int, loc: str) -> dict[str, Any]:
    assert r.status_code == status, r.text
    body: dict[str, Any] = r.json()
    assert body["error"] == "validation_error" if status == 422 else True
    assert body["fields"][0]["loc"] == loc, body
    return body


# ---------------------------------------------------------------------------------- 1. epoch time window


def test_epoch_dated_far_ahead_is_422_naming_time_and_changes_nothing(make_app: MakeApp) -> None:
    store = MemoryStore()
    client = make_app(store)
    assert client.post(EPOCHS, json=payloads.epoch("e0", 0), headers=auth()).status_code == 200
    before = fingerprint(store)
    typo = payloads.epoch("e1", 1)
    typo["time"] = typo["time"].replace("2026-", "2962-", 1)
    body = _error(client.post(EPOCHS, json=typo, headers=auth()), 422, "time")
    assert "86400 s after the service clock" in body["fields"][0]["msg"]
    assert fingerprint(store) == before
    # the city is not blocked: the next correct epoch commits
    assert client.post(EPOCHS, json=payloads.epoch("e2", 2), headers=auth()).status_code == 200


def test_window_follows_the_setting_and_the_clock(make_app: MakeApp) -> None:
    clock = Clock(T0.timestamp())
    client = make_app(clock=clock, epoch_max_ahead_s=600)
    _error(client.post(EPOCHS, json=payloads.epoch("e1", 11), headers=auth()), 422, "time")
    assert client.post(EPOCHS, json=payloads.epoch("e1", 10), headers=auth()).status_code == 200
    clock.now_s += 3600
    assert client.post(EPOCHS, json=payloads.epoch("e2", 70), headers=auth()).status_code == 200
    # epochs far older than the clock (replays of history) are accepted
    clock.now_s += 30 * 86400
    old = payloads.epoch("e3", 71)
    assert client.post(EPOCHS, json=old, headers=auth()).status_code == 200


def _blocked(make_app: MakeApp, store: Store) -> TestClient:
    """A city blocked the way it was before the window existed: an epoch in year 2962 committed."""
    lax = make_app(store, epoch_max_ahead_s=10**12)
    assert lax.post(EPOCHS, json=payloads.epoch("e0", 0), headers=auth()).status_code == 200
    typo = payloads.epoch("e-typo", 1)
    typo["time"] = typo["time"].replace("2026-", "2962-", 1)
    for rider in typo["riders"]:
        rider["requested_at"] = rider["requested_at"].replace("2026-", "2962-", 1)
    assert lax.post(EPOCHS, json=typo, headers=auth()).status_code == 200
    client = make_app(store)
    r = client.post(EPOCHS, json=payloads.epoch("e2", 2), headers=auth())
    assert r.status_code == 409 and r.json()["error"] == "stale_epoch"
    return client


def test_admin_rewind_unblocks_the_city(make_app: MakeApp, any_store: Store) -> None:
    client = _blocked(make_app, any_store)
    rewind = f"/v1/cities/{CITY}/admin/rewind"
    to = rfc(payloads.at(0))
    # the wrong scope, a missing or wrong confirmation, a time ahead of the last: refused, nothing changes
    before = fingerprint(any_store)
    r = client.post(rewind, json={"to": to, "confirm": CITY}, headers=auth())
    assert r.status_code == 403
    _error(client.post(rewind, json={"to": to}, headers=auth(ADMIN)), 422, "confirm")
    _error(client.post(rewind, json={"to": to, "confirm": "other"}, headers=auth(ADMIN)), 422, "confirm")
    ahead = {"to": "2999-01-01T00:00:00Z", "confirm": CITY}
    _error(client.post(rewind, json=ahead, headers=auth(ADMIN)), 422, "to")
    assert fingerprint(any_store) == before

    r = client.post(rewind, json={"to": to, "confirm": CITY}, headers=auth(ADMIN))
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["action"] == "rewind" and out["committed"] == 2
    assert out["previous_last_epoch_time"].startswith("2962-")
    assert dt.datetime.fromisoformat(out["last_epoch_time"]) == payloads.at(0)
    # epochs at the rewound time or later commit again; the log counts them on
    assert client.post(EPOCHS, json=payloads.epoch("e2", 2), headers=auth()).status_code == 200
    log = client.get(EPOCHS, headers=auth()).json()
    assert log["committed"] == 3 and log["last"]["epoch_id"] == "e2"
    # an epoch older than the rewound time is still stale
    r = client.post(EPOCHS, json=payloads.epoch("e-old", -30), headers=auth())
    assert r.status_code == 409 and r.json()["error"] == "stale_epoch"


def test_admin_reset_forgets_the_epoch_stream(make_app: MakeApp, any_store: Store) -> None:
    client = _blocked(make_app, any_store)
    assert client.post(TASKS, json=payloads.tasks(), headers=auth()).status_code == 200
    reset = f"/v1/cities/{CITY}/admin/reset"
    _error(client.post(reset, json={"confirm": "tin"}, headers=auth(ADMIN)), 422, "confirm")
    r = client.post(reset, json={"confirm": CITY}, headers=auth(ADMIN))
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["action"] == "reset" and out["committed"] == 0 and out["last_epoch_time"] is None
    assert out["deleted_keys"] > 0
    assert fingerprint(any_store)[:3] == (0, None, None)
    assert any_store.list_tasks(CITY) == [] and any_store.get_epoch(CITY, "e0") is None
    r = client.get(f"/v1/cities/{CITY}/coverage", headers=auth())
    assert r.status_code == 404 and r.json()["error"] == "no_data"
    # the stream starts again, even with an id used before the reset
    assert client.post(EPOCHS, json=payloads.epoch("e0", 5), headers=auth()).status_code == 200
    assert client.get(EPOCHS, headers=auth()).json()["committed"] == 1


def test_rewind_with_no_epoch_is_404(make_app: MakeApp) -> None:
    client = make_app()
    r = client.post(
        f"/v1/cities/{CITY}/admin/rewind", json={"to": rfc(T0), "confirm": CITY}, headers=auth(ADMIN)
    )
    assert r.status_code == 404 and r.json()["error"] == "no_data"


# ---------------------------------------------------------------------------------- 2. amplification

MiB = 1 << 20


def _fill(prefix: bytes, item: bytes, suffix: bytes, size: int = MiB - 512) -> bytes:
    n = (size - len(prefix) - len(suffix)) // (len(item) + 1)
    return prefix + b",".join([item] * n) + suffix


EPOCH_HEAD = b'{"epoch_id":"e1","time":"' + rfc(T0).encode() + b'",'
AMPLIFIERS = {
    "350,000 empty riders": _fill(EPOCH_HEAD + b'"riders":[', b"{}", b'],"taxis":[]}'),
    "taxis of zeros": _fill(EPOCH_HEAD + b'"riders":[],"taxis":[', b"0", b"]}"),
    "one rider with 90,000 unknown fields": EPOCH_HEAD
    + b'"riders":[{'
    + b",".join(f'"k{i}":0'.encode() for i in range(90_000))
    + b'}],"taxis":[]}',
}


@pytest.mark.parametrize("name", list(AMPLIFIERS))
def test_hostile_epoch_body_gets_a_small_capped_422(make_app: MakeApp, name: str) -> None:
    store = MemoryStore()
    client = make_app(store)
    raw = AMPLIFIERS[name]
    assert len(raw) <= MiB
    r = client.post(EPOCHS, content=raw, headers=auth() | {"Content-Type": "application/json"})
    assert r.status_code == 422, r.text[:300]
    assert len(r.content) < 16 * 1024, len(r.content)  # an uncapped error lists every item: 75 MiB
    body = r.json()
    assert body["error"] == "validation_error" and 1 <= len(body["fields"]) <= MAX_FIELDS
    assert fingerprint(store) == fingerprint(MemoryStore())


def test_too_many_items_refused_before_validating_them(make_app: MakeApp) -> None:
    client = make_app()
    r = client.post(EPOCHS, content=AMPLIFIERS["350,000 empty riders"], headers=auth())
    body = r.json()
    assert [f["loc"] for f in body["fields"]] == ["riders"]
    assert "at most 2000 items per request, got 349" in body["fields"][0]["msg"]
    r = client.post(TASKS, content=_fill(b"[", b"{}", b"]"), headers=auth())
    assert r.status_code == 422 and [f["loc"] for f in r.json()["fields"]] == ["body"]
    r = client.post("/v1/dro/worst-case", content=_fill(b'{"samples":[', b"1", b"]}"), headers=auth())
    assert r.status_code == 422 and [f["loc"] for f in r.json()["fields"]] == ["samples"]


def test_many_field_errors_are_capped_and_counted(make_app: MakeApp) -> None:
    client = make_app()
    body = payloads.epoch("e1")
    body["riders"] = [{} for _ in range(2000)]  # within the limit: 4 missing fields each
    r = client.post(EPOCHS, json=body, headers=auth())
    out = r.json()
    assert r.status_code == 422 and len(out["fields"]) == MAX_FIELDS
    assert out["fields"][0] == {"loc": "riders[0].id", "msg": "Field required"}
    assert "(and 7999 more; the first 50 are listed)" in out["detail"]


# ---------------------------------------------------------------------------------- 3. extreme offsets

EXTREME = "0001-01-01T00:00:00+23:59"


@pytest.mark.parametrize(
    ("where", "loc"),
    [("time", "time"), ("riders.0.requested_at", "riders[0].requested_at")],
)
def test_extreme_offsets_in_an_epoch_are_422(make_app: MakeApp, where: str, loc: str) -> None:
    client = make_app()
    body = payloads.epoch("e1")
    if where == "time":
        body["time"] = EXTREME
    else:
        body["riders"][0]["requested_at"] = EXTREME
    _error(client.post(EPOCHS, json=body, headers=auth()), 422, loc)


def test_extreme_offsets_in_tasks_and_coverage_are_422(make_app: MakeApp) -> None:
    client = make_app()
    tasks = payloads.tasks()
    tasks[1]["scheduled_at"] = EXTREME
    _error(client.post(TASKS, json=tasks, headers=auth()), 422, "[1].scheduled_at")
    for path in ("coverage", "coverage.geojson"):
        for interval in ("9999-12-31T23:59:59-23:59", EXTREME, "9999-12-31T23:00", "0001-01-01T00:00"):
            r = client.get(f"/v1/cities/{CITY}/{path}", params={"interval": interval}, headers=auth(READ))
            _error(r, 422, "interval")


# ---------------------------------------------------------------------------------- 6. lost commit reply


class ResendsCommits(MemoryStore):
    """A store whose commits are applied, then sent again, as redis-py does when the reply is lost."""

    def commit_epoch(self, city: str, commit: EpochCommit) -> CommitResult:
        first = super().commit_epoch(city, commit)
        assert first.status == "committed"
        return super().commit_epoch(city, commit)


def test_lost_commit_reply_is_reported_as_committed(make_app: MakeApp) -> None:
    store = ResendsCommits()
    client = make_app(store)
    r = client.post(EPOCHS, json=payloads.epoch("e1"), headers=auth())
    assert r.status_code == 200 and "Idempotent-Replayed" not in r.headers
    assert fingerprint(store)[0] == 1  # applied once
    # a client's retry of the same post is a replay, and says so
    again = client.post(EPOCHS, json=payloads.epoch("e1"), headers=auth())
    assert again.headers.get("Idempotent-Replayed") == "true" and again.content == r.content
    text = client.get("/metrics").text
    assert 'sd_epochs_total{outcome="committed"} 1.0' in text
    assert 'sd_epochs_total{outcome="replayed"} 1.0' in text


# ---------------------------------------------------------------------------------- 7. the small things


@pytest.mark.parametrize(
    ("method", "path", "allow"),
    [
        ("DELETE", EPOCHS, "GET, POST"),
        ("PUT", TASKS, "GET, POST"),
        ("POST", "/healthz", "GET"),
        ("GET", "/v1/dro/worst-case", "POST"),
    ],
)
def test_405_names_the_allowed_methods(make_app: MakeApp, method: str, path: str, allow: str) -> None:
    r = make_app().request(method, path, headers=auth())
    assert r.status_code == 405 and r.json()["error"] == "method_not_allowed"
    assert r.headers["Allow"] == allow


def test_openapi_states_what_the_server_checks(make_app: MakeApp) -> None:
    doc = make_app().get("/openapi.json").json()
    schemas = doc["components"]["schemas"]
    node = schemas["LocationIn"]["properties"]["node"]
    assert node["type"] == "integer" and "anyOf" not in node  # null is refused
    time = schemas["EpochIn"]["properties"]["time"]
    assert time["format"] == "date-time" and time["pattern"].startswith("^(19[7-9][0-9]|2[0-9]{3})-")
    assert schemas["EpochIn"]["properties"]["riders"]["maxItems"] == 2000
    interval = next(
        p for p in doc["paths"]["/v1/cities/{city}/coverage"]["get"]["parameters"] if p["name"] == "interval"
    )
    assert "pattern" in interval["schema"]["anyOf"][0]
    body = doc["paths"]["/v1/cities/{city}/epochs"]["post"]["requestBody"]
    assert body["content"]["application/json"]["schema"] == {"$ref": "#/components/schemas/EpochIn"}


def test_server_takes_what_the_openapi_allows(make_app: MakeApp) -> None:
    client = make_app()
    r = client.post("/v1/dro/worst-case", json={"samples": [1.0, 2.0, 3.0], "bins": 2.0}, headers=auth())
    assert r.status_code == 200, r.text  # 2.0 is a JSON Schema integer
    body = payloads.epoch("e1")
    body["riders"][0]["origin"] = {"node": float(node_id(0, 0))}
    assert client.post(EPOCHS, json=body, headers=auth()).status_code == 200
    body = payloads.epoch("e2", 1)
    body["riders"][0]["origin"] = {"node": None}
    _error(client.post(EPOCHS, json=body, headers=auth()), 422, "riders[0].origin.node")


def test_readyz_does_not_say_where_the_store_is(make_app: MakeApp) -> None:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    store = RedisStore(f"redis://127.0.0.1:{port}/0", socket_timeout_s=0.5)
    try:
        r = make_app(store).get("/readyz")
    finally:
        store.close()
    assert r.status_code == 503
    assert r.json() == {"error": "store_unavailable", "detail": "store unreachable", "fields": []}
    assert str(port) not in r.text and "127.0.0.1" not in r.text


def test_json_error_body_is_small_and_json(make_app: MakeApp) -> None:
    r = make_app().post(EPOCHS, content=b'{"epoch_id": "e1",' * 1000, headers=auth())
    assert r.status_code == 400 and json.loads(r.content)["error"] == "bad_json"
