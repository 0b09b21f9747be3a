"""Bearer tokens with scopes: reads need `read`, writes need `dispatch`; health and metrics are open."""

from __future__ import annotations

import pytest

from app.adapters import MemoryStore
from tests.api import payloads
from tests.api.conftest import CITY, DISPATCH, READ, MakeClient, auth, fingerprint

READS = [
    "/v1/cities",
    f"/v1/cities/{CITY}",
    f"/v1/cities/{CITY}/graph",
    f"/v1/cities/{CITY}/tasks",
    f"/v1/cities/{CITY}/coverage?interval=2026-11-23T08:00",
]


@pytest.mark.parametrize("path", READS)
def test_reads_need_the_read_scope(make_client: MakeClient, path: str) -> None:
    client = make_client()
    r = client.get(path)
    assert r.status_code == 401 and r.json()["error"] == "unauthorized"
    assert r.headers["WWW-Authenticate"] == "Bearer"
    assert client.get(path, headers=auth("not-a-token-at-all")).status_code == 401
    assert client.get(path, headers={"Authorization": f"Basic {READ}"}).status_code == 401
    r = client.get(path, headers=auth(DISPATCH))
    assert r.status_code == 403 and r.json()["error"] == "forbidden"
    assert client.get(path, headers=auth(READ)).status_code == 200


def test_writes_need_the_dispatch_scope(make_client: MakeClient) -> None:
    store = MemoryStore()
    client = make_client(store=store)
    for path, body in (
        (f"/v1/cities/{CITY}/epochs", payloads.epoch()),
        (f"/v1/cities/{CITY}/tasks", payloads.tasks()),
    ):
        before = fingerprint(store)
        assert client.post(path, json=body).status_code == 401
        r = client.post(path, json=body, headers=auth(READ))
        assert r.status_code == 403 and r.json()["error"] == "forbidden"
        assert fingerprint(store) == before
        assert client.post(path, json=body, headers=auth(DISPATCH)).status_code == 200


def test_auth_is_checked_before_the_body(make_client: MakeClient) -> None:
    client = make_client()
    r = client.post(f"/v1/cities/{CITY}/epochs", json={"nonsense": True}, headers=auth(READ))
    assert r.status_code == 403


def test_no_tokens_configured_means_nobody_gets_in(make_client: MakeClient) -> None:
    client = make_client(tokens={})
    assert client.get("/v1/cities", headers=auth()).status_code == 401


@pytest.mark.parametrize("path", ["/healthz", "/readyz", "/metrics"])
def test_ops_routes_are_open(make_client: MakeClient, path: str) -> None:
    assert make_client().get(path).status_code == 200
