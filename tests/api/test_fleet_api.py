"""Fleet-sizing routes: recommendation, history, solve requests (queued, never solved in the request), auth
and error bodies, over the memory and the Redis store."""

from __future__ import annotations

import datetime as dt

import pytest

from app.cities import CityRegistry
from app.ports import FleetRecord, Store
from app.schemas_fleet import SolveStatsOut
from app.worker.sizing import HistoryDay, HistoryWindow, SizingConfig, recommendation_body
from services.fleet import plan_fleet
from services.model import IntervalKey
from tests.api.conftest import ALL, DISPATCH, READ, TOKENS, MakeClient, auth
from tests.api.fakes import CITY, T0

ADMIN = "tok-admin-0000001"
WITH_ADMIN = TOKENS | {ADMIN: ["admin"]}
BASE = f"/v1/cities/{CITY}/fleet"


def target(registry: CityRegistry) -> IntervalKey:
    """The tiny city's 09:00 interval on the fixtures' day."""
    return registry.get(CITY).horizon.interval_of(T0.timestamp() + 3600)


def body_json(
    registry: CityRegistry, k: IntervalKey, daily: dict[int, list[float]], request_id: str | None
) -> str:
    """A real recommendation document: a plan from hand-made samples, rendered as the worker renders it."""
    city = registry.get(CITY)
    hours = city.horizon.n_intervals
    hourly = [{x: [v + h for v in samples] for x, samples in daily.items()} for h in range(hours)]
    completion = {x: [0.85 + 0.03 * x] * len(s) for x, s in daily.items()}
    config = SizingConfig(sizes=tuple(sorted(daily)), days=3, completion_target=0.95)
    plan = plan_fleet(daily, hourly, config.ambiguity, completion=completion, target=0.95)
    window = HistoryWindow(
        "synthetic", tuple(HistoryDay(f"synthetic-{d}", d, None) for d in (1, 2, 3)), 0, "three seeded days"
    )
    stats = SolveStatsOut(runs=6, cached_runs=0, wall_s=1.5, jobs=2)
    body = recommendation_body(
        city, k, plan, config, window, [140, 150, 160], stats, trigger="request", request_id=request_id
    )
    return body.model_dump_json()


def publish(store: Store, registry: CityRegistry, version: int, at: dt.datetime, **kw: object) -> FleetRecord:
    k = target(registry)
    daily = kw.pop("daily", {2: [5.0, 6.0, 7.0], 4: [3.0, 3.5, 4.0]})
    record = FleetRecord(
        "published",
        at.timestamp(),
        int(k),
        version=version,
        body_json=body_json(registry, k, daily, "req-1"),  # type: ignore[arg-type]
        request_id="req-1",
    )
    assert store.publish_recommendation(CITY, record, 100).status == "published"
    return record


def test_no_recommendation_yet_is_404_no_data(make_client: MakeClient) -> None:
    client = make_client()
    r = client.get(f"{BASE}/recommendation", headers=auth(READ))
    assert r.status_code == 404
    body = r.json()
    assert body["error"] == "no_data" and "worker" in body["detail"] and body["fields"] == []
    r = client.get(f"{BASE}/recommendations", headers=auth(READ))
    assert r.status_code == 200 and r.json() == {"city": CITY, "entries": []}


def test_unknown_city_is_404_everywhere(make_client: MakeClient) -> None:
    client = make_client(tokens=WITH_ADMIN)
    for method, path, token in (
        ("GET", "/v1/cities/atlantis/fleet/recommendation", READ),
        ("GET", "/v1/cities/atlantis/fleet/recommendations", READ),
        ("POST", "/v1/cities/atlantis/fleet/solve", ADMIN),
    ):
        r = client.request(method, path, headers=auth(token))
        assert r.status_code == 404 and r.json()["error"] == "unknown_city", (method, path)


def test_recommendation_serves_the_published_document(
    make_client: MakeClient, registry: CityRegistry, any_store: Store
) -> None:
    client = make_client(store=any_store)
    at = dt.datetime(2026, 11, 23, 7, 0, 5, tzinfo=dt.UTC)
    publish(any_store, registry, 1, at)
    r = client.get(f"{BASE}/recommendation", headers=auth(READ))
    assert r.status_code == 200, r.text
    rec = r.json()
    assert rec["version"] == 1 and rec["computed_at"] == "2026-11-23T15:00:05+08:00"
    assert rec["interval"] == "2026-11-23T09:00" and rec["position"] == 1
    assert rec["interval_start"] == "2026-11-23T09:00:00+08:00"
    # size 4 is lower on every day: every method picks it; completion 0.85 + 0.03 x meets 0.95 from x = 4
    assert rec["chosen"] == {"deterministic": 4, "dro": 4, "dro_rh": 4, "completion_target": 4}
    assert [row["size"] for row in rec["daily_table"]] == [2, 4]
    row = rec["daily_table"][1]
    assert row["mean"] == pytest.approx(3.5) and row["worst_case"] >= row["mean"]
    assert row["premium"] == pytest.approx(row["worst_case"] - row["mean"])
    assert row["rho"] > 0 and row["m"] == 10 and row["n_samples"] == 3
    assert rec["hour_table"][1]["mean"] == pytest.approx(4.5)  # the 09:00 samples are the daily ones + 1
    assert [h["interval"] for h in rec["dro_rh_by_hour"]] == [
        f"2026-11-23T{h:02d}:00" for h in (8, 9, 10, 11)
    ]
    assert rec["divergence"] == "kl" and rec["alpha"] == 0.05 and rec["support"] == "binned"
    assert rec["data_window"]["source"] == "synthetic" and rec["data_window"]["days"][0] == "synthetic-1"
    assert rec["request_id"] == "req-1" and rec["trigger"] == "request"
    assert rec["completion_target"]["status"] == "met" and rec["completion_target"]["size"] == 4


def test_history_lists_published_and_failed_solves_newest_first(
    make_client: MakeClient, registry: CityRegistry
) -> None:
    client = make_client()
    store = client.app.state.service.store  # type: ignore[attr-defined]
    publish(store, registry, 1, dt.datetime(2026, 11, 23, 0, 0, tzinfo=dt.UTC))
    failure = FleetRecord("failed", T0.timestamp(), int(target(registry)), reason="2 of 6 runs failed: boom")
    store.record_solve_failure(CITY, failure, 100)
    publish(
        store,
        registry,
        2,
        dt.datetime(2026, 11, 23, 1, 0, tzinfo=dt.UTC),
        daily={2: [1.0, 1.0], 4: [2.0, 3.0]},
    )
    r = client.get(f"{BASE}/recommendations", headers=auth(READ))
    assert r.status_code == 200, r.text
    entries = r.json()["entries"]
    assert [(e["status"], e["version"]) for e in entries] == [
        ("published", 2),
        ("failed", None),
        ("published", 1),
    ]
    assert entries[1]["reason"] == "2 of 6 runs failed: boom" and entries[1]["recommendation"] is None
    assert entries[1]["interval"] == "2026-11-23T09:00" and entries[1]["computed_at"] == T0.isoformat()
    assert entries[0]["recommendation"]["chosen"]["dro"] == 2 and entries[0]["recommendation"]["version"] == 2
    # the current one is the last published, not the failure after it
    assert client.get(f"{BASE}/recommendation", headers=auth(READ)).json()["version"] == 2
    r = client.get(f"{BASE}/recommendations?limit=1", headers=auth(READ))
    assert [e["version"] for e in r.json()["entries"]] == [2]
    for bad in ("0", "101", "x"):
        r = client.get(f"{BASE}/recommendations?limit={bad}", headers=auth(READ))
        assert r.status_code == 422 and r.json()["fields"][0]["loc"] == "limit", bad


def test_solve_request_is_queued_not_solved(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store, tokens=WITH_ADMIN)
    r = client.post(f"{BASE}/solve", headers=auth(ADMIN))
    assert r.status_code == 202, r.text
    first = r.json()
    assert first["status"] == "queued" and first["city"] == CITY and first["requested_at"].endswith("+08:00")
    r = client.post(f"{BASE}/solve", headers=auth(ADMIN))
    assert r.status_code == 202 and r.json() | {"status": "queued"} == first
    assert r.json()["status"] == "already_queued"
    # nothing was solved in the request: no recommendation, no history
    assert client.get(f"{BASE}/recommendation", headers=auth(READ)).status_code == 404
    assert any_store.recommendation_history(CITY, 10) == []
    claimed = any_store.claim_solve_request(CITY)
    assert claimed is not None and claimed.request_id == first["request_id"]
    assert claimed.requested_by == ADMIN[:4] + "…"
    r = client.post(f"{BASE}/solve", headers=auth(ADMIN))
    assert r.json()["status"] == "queued" and r.json()["request_id"] != first["request_id"]


def test_scopes(make_client: MakeClient) -> None:
    client = make_client(tokens=WITH_ADMIN)
    assert client.get(f"{BASE}/recommendations").status_code == 401
    assert client.get(f"{BASE}/recommendations", headers=auth(DISPATCH)).status_code == 403
    assert client.get(f"{BASE}/recommendations", headers=auth(ADMIN)).status_code == 403
    for token in (READ, DISPATCH, ALL):
        r = client.post(f"{BASE}/solve", headers=auth(token))
        assert r.status_code == 403 and r.json()["error"] == "forbidden" and "admin" in r.json()["detail"]
    assert client.post(f"{BASE}/solve").status_code == 401
    assert client.post(f"{BASE}/solve", headers=auth(ADMIN)).status_code == 202


def test_an_unreadable_stored_document_is_a_500_with_the_error_shape(make_client: MakeClient) -> None:
    client = make_client(raise_errors=False)
    store = client.app.state.service.store  # type: ignore[attr-defined]
    record = FleetRecord("published", T0.timestamp(), 0, version=1, body_json='{"city": "tiny"}')
    assert store.publish_recommendation(CITY, record, 10).status == "published"
    r = client.get(f"{BASE}/recommendation", headers=auth(READ))
    assert r.status_code == 500
    assert r.json()["error"] == "internal" and "version 1 cannot be read" in r.json()["detail"]
