"""Every malformed request: exact status, error kind and ``fields[0].loc``, and the store left untouched."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.adapters import MemoryStore
from tests.api import payloads
from tests.api.conftest import CITY, MakeClient, auth, fingerprint
from tests.api.fakes import node_id

EPOCHS = f"/v1/cities/{CITY}/epochs"
TASKS = f"/v1/cities/{CITY}/tasks"
JSON = {"Content-Type": "application/json"}

Mutation = Callable[[dict[str, Any]], None]


def _set(path: str, value: Any) -> Mutation:
    """Set ``value`` at a dotted/indexed path such as ``riders.0.origin.lon`` (``...`` deletes)."""

    def mutate(body: dict[str, Any]) -> None:
        *head, last = path.split(".")
        node: Any = body
        for part in head:
            node = node[int(part)] if part.isdigit() else node[part]
        key: Any = int(last) if last.isdigit() else last
        if value is ...:
            del node[key]
        else:
            node[key] = value

    return mutate


LONG = "x" * 200
EPOCH_CASES: list[tuple[str, Mutation, int, str, str]] = [
    ("missing taxis", _set("taxis", ...), 422, "validation_error", "taxis"),
    ("missing epoch_id", _set("epoch_id", ...), 422, "validation_error", "epoch_id"),
    ("extra top-level field", _set("weather", "rain"), 422, "validation_error", "weather"),
    (
        "extra field in a location",
        _set("riders.0.origin.alt", 3),
        422,
        "validation_error",
        "riders[0].origin.alt",
    ),
    ("extra field in a taxi", _set("taxis.1.speed", 3), 422, "validation_error", "taxis[1].speed"),
    ("duplicate rider ids", _set("riders.1.id", "r1"), 422, "validation_error", "riders[1].id"),
    ("duplicate taxi ids", _set("taxis.2.id", "t0"), 422, "validation_error", "taxis[2].id"),
    (
        "lon/lat off the network",
        _set("riders.1.origin", {"lon": 104.2, "lat": 30.66}),
        422,
        "validation_error",
        "riders[1].origin",
    ),
    (
        "unknown node id",
        _set("taxis.0.location", {"node": 42}),
        422,
        "validation_error",
        "taxis[0].location.node",
    ),
    (
        "unknown destination node",
        _set("riders.0.destination.node", 7),
        422,
        "validation_error",
        "riders[0].destination.node",
    ),
    (
        "node and lon/lat together",
        _set("riders.0.origin.lon", 104.06),
        422,
        "validation_error",
        "riders[0].origin",
    ),
    ("lat without lon", _set("riders.0.origin", {"lat": 30.66}), 422, "validation_error", "riders[0].origin"),
    (
        "node id as float",
        _set("riders.0.origin.node", 1000.5),
        422,
        "validation_error",
        "riders[0].origin.node",
    ),
    (
        "node id as string",
        _set("riders.0.origin.node", "1000"),
        422,
        "validation_error",
        "riders[0].origin.node",
    ),
    ("lon beyond 180", _set("riders.1.origin.lon", 181.0), 422, "validation_error", "riders[1].origin.lon"),
    ("lat beyond 90", _set("riders.1.origin.lat", -95.0), 422, "validation_error", "riders[1].origin.lat"),
    ("lon as string", _set("riders.1.origin.lon", "104.06"), 422, "validation_error", "riders[1].origin.lon"),
    ("naive time", _set("time", "2026-11-23T08:00:00"), 422, "validation_error", "time"),
    ("time without seconds", _set("time", "2026-11-23T08:00+08:00"), 422, "validation_error", "time"),
    ("time as a number", _set("time", 1795392000), 422, "validation_error", "time"),
    ("date only", _set("time", "2026-11-23"), 422, "validation_error", "time"),
    ("impossible date", _set("time", "2026-13-40T08:00:00+08:00"), 422, "validation_error", "time"),
    ("absurd year", _set("time", "1900-11-23T08:00:00+08:00"), 422, "validation_error", "time"),
    (
        "naive requested_at",
        _set("riders.0.requested_at", "2026-11-23T07:59:00"),
        422,
        "validation_error",
        "riders[0].requested_at",
    ),
    (
        "requested_at after the epoch",
        _set("riders.1.requested_at", "2026-11-23T08:00:01+08:00"),
        422,
        "validation_error",
        "riders[1].requested_at",
    ),
    ("id too long", _set("riders.0.id", LONG), 422, "validation_error", "riders[0].id"),
    ("empty id", _set("taxis.0.id", ""), 422, "validation_error", "taxis[0].id"),
    ("control character in id", _set("epoch_id", "e\n1"), 422, "validation_error", "epoch_id"),
    ("epoch id too long", _set("epoch_id", LONG), 422, "validation_error", "epoch_id"),
    ("bad status", _set("taxis.0.status", "parked"), 422, "validation_error", "taxis[0].status"),
    (
        "instrumented as string",
        _set("taxis.0.instrumented", "yes"),
        422,
        "validation_error",
        "taxis[0].instrumented",
    ),
    (
        "instrumented as int",
        _set("taxis.0.instrumented", 1),
        422,
        "validation_error",
        "taxis[0].instrumented",
    ),
    ("riders not a list", _set("riders", {"id": "r1"}), 422, "validation_error", "riders"),
    ("rider not an object", _set("riders.0", "r1"), 422, "validation_error", "riders[0]"),
]


@pytest.fixture
def client_store(make_client: MakeClient) -> tuple[TestClient, MemoryStore]:
    """A client whose store already holds tasks and one committed epoch (at T0 - 1 min)."""
    store = MemoryStore()
    client = make_client(store=store, max_riders=5, max_taxis=5, max_tasks=3, max_body_bytes=64 * 1024)
    assert client.post(TASKS, json=payloads.tasks(), headers=auth()).status_code == 200
    assert client.post(EPOCHS, json=payloads.epoch("e0", -1), headers=auth()).status_code == 200
    return client, store


def _check(r: Any, status: int, kind: str, loc: str | None) -> None:
    assert r.status_code == status, r.text
    body = r.json()
    assert set(body) == {"error", "detail", "fields"}
    assert body["error"] == kind
    assert isinstance(body["detail"], str) and body["detail"]
    if loc is not None:
        assert body["fields"][0]["loc"] == loc, body
        assert body["fields"][0]["msg"]


@pytest.mark.parametrize(
    ("name", "mutate", "status", "kind", "loc"), EPOCH_CASES, ids=[c[0] for c in EPOCH_CASES]
)
def test_bad_epoch_rejected_and_store_unchanged(
    client_store: tuple[TestClient, MemoryStore],
    name: str,
    mutate: Mutation,
    status: int,
    kind: str,
    loc: str,
) -> None:
    client, store = client_store
    body = payloads.epoch("e1", 0)
    mutate(body)
    before = fingerprint(store)
    _check(client.post(EPOCHS, json=body, headers=auth()), status, kind, loc)
    assert fingerprint(store) == before


RAW_CASES: list[tuple[str, bytes, dict[str, str], int, str, str]] = [
    ("not JSON", b'{"epoch_id": "e1",', JSON, 400, "bad_json", "body"),
    ("empty body", b"", JSON, 422, "validation_error", "body"),
    ("a list instead of an object", b"[]", JSON, 422, "validation_error", "body"),
    (
        "text/plain",
        json.dumps(payloads.epoch()).encode(),
        {"Content-Type": "text/plain"},
        415,
        "unsupported_media_type",
        "body",
    ),
    (
        "NaN lon",
        json.dumps(payloads.epoch("e1"))
        .replace('"origin": {"lon": ', '"origin": {"lon": NaN, "x": ')
        .encode(),
        JSON,
        422,
        "validation_error",
        "riders[1].origin.lon",
    ),
    (
        "Infinity lat",
        json.dumps(payloads.epoch("e1")).replace('"lat": ', '"lat": Infinity, "y": ', 1).encode(),
        JSON,
        422,
        "validation_error",
        "riders[1].origin.lat",
    ),
]


@pytest.mark.parametrize(
    ("name", "raw", "headers", "status", "kind", "loc"), RAW_CASES, ids=[c[0] for c in RAW_CASES]
)
def test_malformed_body_rejected(
    client_store: tuple[TestClient, MemoryStore],
    name: str,
    raw: bytes,
    headers: dict[str, str],
    status: int,
    kind: str,
    loc: str,
) -> None:
    client, store = client_store
    before = fingerprint(store)
    _check(client.post(EPOCHS, content=raw, headers=auth() | headers), status, kind, loc)
    assert fingerprint(store) == before


def test_too_many_riders_and_taxis(client_store: tuple[TestClient, MemoryStore]) -> None:
    client, store = client_store
    before = fingerprint(store)
    body = payloads.epoch("e1")
    body["riders"] = [dict(body["riders"][0], id=f"r{i}") for i in range(6)]
    _check(client.post(EPOCHS, json=body, headers=auth()), 422, "validation_error", "riders")
    body = payloads.epoch("e1")
    body["taxis"] = [dict(body["taxis"][0], id=f"t{i}") for i in range(6)]
    _check(client.post(EPOCHS, json=body, headers=auth()), 422, "validation_error", "taxis")
    assert fingerprint(store) == before


def test_oversized_body_is_413(client_store: tuple[TestClient, MemoryStore]) -> None:
    client, store = client_store
    before = fingerprint(store)
    body = payloads.epoch("e1")
    body["riders"] = [dict(body["riders"][0], id=f"r{i:06d}") for i in range(1000)]  # ~150 kB > 64 kB
    raw = json.dumps(body).encode()
    _check(client.post(EPOCHS, content=raw, headers=auth() | JSON), 413, "payload_too_large", None)

    def chunks() -> Iterator[bytes]:  # no Content-Length: the actual bytes are counted
        for i in range(0, len(raw), 8192):
            yield raw[i : i + 8192]

    r = client.post(EPOCHS, content=chunks(), headers=auth() | JSON)
    assert "content-length" not in r.request.headers
    _check(r, 413, "payload_too_large", None)
    _check(client.post(TASKS, content=raw, headers=auth() | JSON), 413, "payload_too_large", None)
    assert fingerprint(store) == before


def test_unknown_city_is_404(client_store: tuple[TestClient, MemoryStore]) -> None:
    client, store = client_store
    before = fingerprint(store)
    _check(
        client.post("/v1/cities/atlantis/epochs", json=payloads.epoch("e1"), headers=auth()),
        404,
        "unknown_city",
        None,
    )
    _check(
        client.post("/v1/cities/atlantis/tasks", json=payloads.tasks(), headers=auth()),
        404,
        "unknown_city",
        None,
    )
    for path in ("", "/graph", "/tasks", "/coverage"):
        _check(client.get(f"/v1/cities/atlantis{path}", headers=auth()), 404, "unknown_city", None)
    assert fingerprint(store) == before


def test_unknown_route_and_method(client_store: tuple[TestClient, MemoryStore]) -> None:
    client, _ = client_store
    _check(client.get("/v2/nothing", headers=auth()), 404, "not_found", None)
    _check(client.delete(EPOCHS, headers=auth()), 405, "method_not_allowed", None)


TASK_CASES: list[tuple[str, Callable[[list[dict[str, Any]]], None], int, str, str]] = [
    ("duplicate ids", lambda b: b[1].update(id="poi-a"), 422, "validation_error", "[1].id"),
    (
        "naive scheduled_at",
        lambda b: b[0].update(scheduled_at="2026-11-23T08:00:00"),
        422,
        "validation_error",
        "[0].scheduled_at",
    ),
    (
        "off the network",
        lambda b: b[1].update(location={"lon": 10.0, "lat": 10.0}),
        422,
        "validation_error",
        "[1].location",
    ),
    (
        "unknown node",
        lambda b: b[0].update(location={"node": 5}),
        422,
        "validation_error",
        "[0].location.node",
    ),
    ("extra field", lambda b: b[0].update(priority=1), 422, "validation_error", "[0].priority"),
    ("missing location", lambda b: b[0].pop("location"), 422, "validation_error", "[0].location"),
    (
        "too many",
        lambda b: b.extend(dict(b[0], id=f"x{i}") for i in range(2)),
        422,
        "validation_error",
        "body",
    ),
    (
        "conflicting content",
        lambda b: b[0].update(location={"node": node_id(1, 1)}),
        409,
        "task_conflict",
        "[0].id",
    ),
]


@pytest.mark.parametrize(
    ("name", "mutate", "status", "kind", "loc"), TASK_CASES, ids=[c[0] for c in TASK_CASES]
)
def test_bad_tasks_rejected_and_store_unchanged(
    client_store: tuple[TestClient, MemoryStore],
    name: str,
    mutate: Callable[[list[dict[str, Any]]], None],
    status: int,
    kind: str,
    loc: str,
) -> None:
    client, store = client_store
    body = payloads.tasks()
    body.append(
        {"id": "poi-c", "location": {"node": node_id(2, 2)}, "scheduled_at": payloads.at(0).isoformat()}
    )
    mutate(body)
    before = fingerprint(store)
    r = client.post(TASKS, json=body, headers=auth())
    _check(r, status, kind, loc)
    if status == 409:
        assert "poi-a" in r.json()["detail"]
    assert fingerprint(store) == before


def test_tasks_are_idempotent(client_store: tuple[TestClient, MemoryStore]) -> None:
    client, store = client_store
    r = client.post(TASKS, json=payloads.tasks(), headers=auth())
    assert r.status_code == 200 and r.json() == {"created": [], "unchanged": ["poi-a", "poi-b"]}


def test_bad_coverage_interval(client_store: tuple[TestClient, MemoryStore]) -> None:
    client, _ = client_store
    for bad in ("yesterday", "2026-11-23T08:30", "2026-11-23T08:00:00", "2026-02-30T08:00"):
        _check(
            client.get(f"/v1/cities/{CITY}/coverage", params={"interval": bad}, headers=auth()),
            422,
            "validation_error",
            "interval",
        )
    _check(
        client.get(f"/v1/cities/{CITY}/coverage", params={"interval": "x" * 100}, headers=auth()),
        422,
        "validation_error",
        "interval",
    )
