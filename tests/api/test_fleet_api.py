"""Fleet-sizing routes: recommendation, history, solve requests (queued, never solved in the request), auth
and error bodies, over the memory and the Redis store."""

from __future__ import annotations

import datetime as dt
import json
import time
from zoneinfo import ZoneInfo

import pytest
from fastapi.testclient import TestClient

from app.adapters.city_registry import CityRegistry
from app.ports import (
    EpochCommit,
    FleetRecord,
    SolveProgress,
    SolveRequest,
    Store,
    Waiting,
    WorkerBeat,
    local_day,
)
from app.schemas.fleet import render_recommendation
from app.usecases.fleet_history import SizingConfig
from app.usecases.fleet_solve import (
    FleetOrigin,
    HistoryDay,
    HistoryWindow,
    Observed,
    Recommendation,
    SolveStats,
    TaskSet,
)
from services.city import Horizon
from services.fleet.sizing import CostModel, DayOutcomes, plan_fleet
from services.model import IntervalKey
from services.rfc3339 import format_time
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
    """A real recommendation document: a plan from hand-made outcomes, rendered as the worker renders it.

    Day ``j`` of size ``x`` costs ``daily[x][j] + h`` CNY in hour ``h``; 5 reachable tasks are due every hour
    and ``min(5, x + 2)`` of them are done. The three history days had 30, 40 and 50 requests an hour; the
    day solved for showed 41 in its first hour."""
    city = registry.get(CITY)
    hours = city.horizon.n_intervals
    outcomes = {
        x: DayOutcomes.of(
            [[v + h for h in range(hours)] for v in s],
            [[5] * hours] * len(s),
            [[min(5, x + 2)] * hours] * len(s),
        )
        for x, s in daily.items()
    }
    n_days = len(next(iter(daily.values())))
    volumes = [[30.0 + 10.0 * j] * hours for j in range(n_days)]
    config = SizingConfig(
        sizes=tuple(sorted(daily)),
        days=3,
        completion_target=0.95,
        subsidy_cny_per_vehicle_hour=0.25,
        rolling_days=2,
    )
    observed = Observed("2026-11-23", (41,))
    plan = plan_fleet(
        outcomes,
        volumes,
        config.ambiguity,
        CostModel(0.25),
        observed=observed.requests_per_hour,
        keep=2,
        target=0.95,
    )
    window = HistoryWindow(
        "synthetic",
        tuple(HistoryDay(f"synthetic-{d}", d, None) for d in range(1, n_days + 1)),
        0,
        "three seeded days",
    )
    stats = SolveStats(runs=6, cached_runs=0, wall_s=1.5, jobs=2)
    rec = Recommendation(
        city,
        k,
        plan,
        config,
        window,
        (140, 150, 160)[:n_days],
        stats,
        "request",
        request_id,
        observed,
        TaskSet("synthetic", None),
        FleetOrigin("settings", "settings", None, None, "seeded"),
    )
    return render_recommendation(rec)


def solve_day() -> dt.date:
    """The local date of the hour a solve now is for (the tiny city's coming hour)."""
    hz = Horizon()  # the tiny city's: Asia/Shanghai, 08:00-12:00
    return hz.local_start(hz.coming_interval(time.time())).date()


def record_history(store: Store, days: int = 2) -> None:
    """An epoch on each of the ``days`` local days before today: the history a solve with M = ``days``
    needs (the clients below set ``worker_days=2``)."""
    tz = ZoneInfo("Asia/Shanghai")
    version = store.load_state(CITY, [], []).version
    for back in range(days, 0, -1):
        t = dt.datetime.combine(solve_day() - dt.timedelta(days=back), dt.time(9), tzinfo=tz).timestamp()
        doc = json.dumps({"epoch_id": f"h{back}", "time_s": t, "riders": []})
        commit = EpochCommit(
            f"h{back}", "h", t, version, (), (), "{}", demand_json=doc, demand_day=local_day(t, tz.key)
        )
        assert store.commit_epoch(CITY, commit).status == "committed"
        version += 1


def beat(age_s: float = 1.0, now: float | None = None, **kw: object) -> WorkerBeat:
    """A worker's heartbeat written ``age_s`` seconds before ``now`` (default: the time of the call)."""
    now = time.time() if now is None else now
    base: dict[str, object] = {
        "started_at_s": now - 600.0,
        "host": "box-1",
        "pid": 77,
        "embedded": False,
        "poll_s": 5.0,
    }
    return WorkerBeat("box-1:77:abc", now - age_s, **(base | kw))  # type: ignore[arg-type]


def store_of(client: TestClient) -> Store:
    """The app's store."""
    store: Store = client.app.state.use_cases.fleet.store  # type: ignore[attr-defined]
    return store


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
    # size 4 is cheaper on every day and the only one completing >= 0.95 of the reachable tasks
    assert rec["chosen"] == {"deterministic": 4, "dro": 4, "box_lp": 4, "dro_rh": 4}
    assert rec["subsidy_cny_per_vehicle_hour"] == 0.25 and rec["completion_target"] == 0.95
    assert [row["size"] for row in rec["candidates"]] == [2, 4]
    row = rec["candidates"][1]
    # total cost per hour of day j: mean over hours of (daily + h) + 0.25 * 4 = daily + 1.5 + 1
    assert row["samples"] == pytest.approx([5.5, 6.0, 6.5])
    assert row["mean_cost_cny_per_h"] == pytest.approx(6.0) and row["design_kpi_mean"] == pytest.approx(1.5)
    assert row["worst_case_cost_cny_per_h"] >= row["mean_cost_cny_per_h"]
    assert row["premium_cny_per_h"] == pytest.approx(
        row["worst_case_cost_cny_per_h"] - row["mean_cost_cny_per_h"]
    )
    # the box LP puts the mass on bin midpoints: the top one is 6.5 - 0.1 / 2, its saturated worst case
    assert row["box_lp_worst_case_cny_per_h"] == pytest.approx(6.45)
    assert row["rho"] > 0 and row["m"] == 10 and row["n_samples"] == 3
    assert row["completion_mean"] == 1.0 and rec["candidates"][0]["completion_worst_case"] == pytest.approx(
        0.8
    )
    assert (
        sorted(row["picked_by"]) == ["box_lp", "deterministic", "dro"]
        and rec["candidates"][0]["picked_by"] == []
    )
    assert rec["deterministic"]["target_met"] is True
    # hour 0 had nothing to condition on; from hour 1 on, the two days closest to 41 requests an hour
    by_hour = rec["dro_rh_by_hour"]
    assert [h["interval"] for h in by_hour] == [f"2026-11-23T{h:02d}:00" for h in (8, 9, 10, 11)]
    assert (
        by_hour[0]["days"] == ["synthetic-1", "synthetic-2", "synthetic-3"]
        and by_hour[0]["observed_hours"] == 0
    )
    assert by_hour[1]["days"] == ["synthetic-2", "synthetic-3"] and by_hour[1]["observed_hours"] == 1
    # days 2 and 3 of size 4 in hour 1: (3.5 + 1, 4.0 + 1) + 0.25 * 4
    assert by_hour[1]["candidates"][1]["samples"] == pytest.approx([5.5, 6.0])
    assert rec["dro_rh"] == by_hour[1] and rec["observed"] == {
        "date": "2026-11-23",
        "hours": 1,
        "requests_per_hour": [41],
    }
    assert rec["divergence"] == "kl" and rec["alpha"] == 0.05 and rec["support"] == "binned"
    assert rec["data_window"]["source"] == "synthetic" and rec["data_window"]["days"][0] == "synthetic-1"
    assert rec["request_id"] == "req-1" and rec["trigger"] == "request"
    assert rec["simulation"]["tasks_source"] == "synthetic"


def test_history_lists_published_and_failed_solves_newest_first(
    make_client: MakeClient, registry: CityRegistry
) -> None:
    client = make_client()
    store = client.app.state.use_cases.fleet.store  # type: ignore[attr-defined]
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
    # size 2 is cheaper in version 2, but completes 0.8 < 0.95 of the reachable tasks: the target keeps 4
    newest = entries[0]["recommendation"]
    assert newest["chosen"]["dro"] == 4 and newest["version"] == 2 and newest["dro"]["target_met"] is True
    assert newest["candidates"][0]["mean_cost_cny_per_h"] < newest["candidates"][1]["mean_cost_cny_per_h"]
    # the current one is the last published, not the failure after it
    assert client.get(f"{BASE}/recommendation", headers=auth(READ)).json()["version"] == 2
    r = client.get(f"{BASE}/recommendations?limit=1", headers=auth(READ))
    assert [e["version"] for e in r.json()["entries"]] == [2]
    for bad in ("0", "101", "x"):
        r = client.get(f"{BASE}/recommendations?limit={bad}", headers=auth(READ))
        assert r.status_code == 422 and r.json()["fields"][0]["loc"] == "limit", bad


def test_solve_request_is_queued_not_solved(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store, tokens=WITH_ADMIN, worker_days=2)
    record_history(any_store)
    any_store.record_worker_beat(CITY, beat(), 3600.0)
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
    client = make_client(tokens=WITH_ADMIN, worker_days=2)
    record_history(store_of(client))
    assert client.get(f"{BASE}/recommendations").status_code == 401
    assert client.get(f"{BASE}/recommendations", headers=auth(DISPATCH)).status_code == 403
    assert client.get(f"{BASE}/recommendations", headers=auth(ADMIN)).status_code == 403
    for token in (READ, DISPATCH, ALL):
        r = client.post(f"{BASE}/solve", headers=auth(token))
        assert r.status_code == 403 and r.json()["error"] == "forbidden" and "admin" in r.json()["detail"]
    assert client.post(f"{BASE}/solve").status_code == 401
    store_of(client).record_worker_beat(CITY, beat(), 3600.0)
    assert client.post(f"{BASE}/solve", headers=auth(ADMIN)).status_code == 202
    assert client.get(f"{BASE}/status").status_code == 401
    assert client.get(f"{BASE}/status", headers=auth(DISPATCH)).status_code == 403
    assert client.get(f"{BASE}/status", headers=auth(READ)).status_code == 200


def test_an_unreadable_stored_document_is_a_500_with_the_error_shape(make_client: MakeClient) -> None:
    client = make_client(raise_errors=False)
    store = client.app.state.use_cases.fleet.store  # type: ignore[attr-defined]
    record = FleetRecord("published", T0.timestamp(), 0, version=1, body_json='{"city": "tiny"}')
    assert store.publish_recommendation(CITY, record, 10).status == "published"
    r = client.get(f"{BASE}/recommendation", headers=auth(READ))
    assert r.status_code == 500
    assert r.json()["error"] == "internal" and "version 1 cannot be read" in r.json()["detail"]


@pytest.mark.parametrize("age_s", [None, 31.0, 3000.0])
def test_a_solve_request_with_no_worker_seen_is_503_no_worker_and_queues_nothing(
    make_client: MakeClient, any_store: Store, age_s: float | None
) -> None:
    now = time.time()  # the service's clock stands still: the beat is exactly age_s old
    client = make_client(store=any_store, tokens=WITH_ADMIN, clock=lambda: now, worker_days=2)  # stale: 30 s
    record_history(any_store)
    if age_s is not None:
        any_store.record_worker_beat(CITY, beat(age_s, now), 3600.0)
    r = client.post(f"{BASE}/solve", headers=auth(ADMIN))
    assert r.status_code == 503, r.text
    body = r.json()
    assert body["error"] == "no_worker" and body["fields"] == []
    assert "python -m app worker" in body["detail"] and "in the last 30 s" in body["detail"]
    assert ("never" if age_s is None else f"last seen {age_s:.0f} s ago (box-1)") in body["detail"]
    assert any_store.pending_solve_request(CITY) is None
    status = client.get(f"{BASE}/status", headers=auth(READ)).json()
    assert status["worker"]["seen"] is False and "python -m app worker" in status["worker"]["hint"]
    assert status["pending_request"] is None


def test_the_stale_limit_is_a_setting(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store, tokens=WITH_ADMIN, worker_stale_s=120.0, worker_days=2)
    record_history(any_store)
    any_store.record_worker_beat(CITY, beat(90.0), 3600.0)
    assert client.post(f"{BASE}/solve", headers=auth(ADMIN)).status_code == 202


def test_before_its_history_a_solve_is_409_and_the_status_counts_the_days(
    make_client: MakeClient, any_store: Store
) -> None:
    """A city sized on the platform's own history: until it has M days with epochs a solve request is
    refused with the days it has and needs (nothing queued), and the status says how far it is."""
    client = make_client(store=any_store, tokens=WITH_ADMIN, worker_days=3)
    any_store.record_worker_beat(CITY, beat(), 3600.0)
    record_history(any_store, days=2)
    r = client.post(f"{BASE}/solve", headers=auth(ADMIN))
    assert r.status_code == 409, r.text
    body = r.json()
    first = (solve_day() + dt.timedelta(days=1)).isoformat()
    assert body["error"] == "insufficient_history" and body["fields"] == []
    assert body["history"] == {"days": 2, "needed": 3, "first_solve_on": first}
    assert "collecting history: 2 of 3 days" in body["detail"]
    assert any_store.pending_solve_request(CITY) is None
    st = client.get(f"{BASE}/status", headers=auth(READ)).json()
    assert st["history"] == {
        "days": 2,
        "needed": 3,
        "first_solve_on": first,
        "enough": False,
        "until_then": "none",
        "text": body["detail"].removeprefix("'tiny' cannot be sized yet: "),
    }
    assert st["history"]["text"].startswith("collecting history: 2 of 3 days")
    # a worker that found the city not sizable says why, once, in its beat
    waiting = Waiting("insufficient_history", st["history"]["text"], time.time() - 5.0)
    any_store.record_worker_beat(CITY, beat(waiting=waiting), 3600.0)
    st = client.get(f"{BASE}/status", headers=auth(READ)).json()
    assert st["waiting"]["kind"] == "insufficient_history" and st["waiting"]["reason"] == waiting.reason
    other = make_client(store=any_store, tokens=WITH_ADMIN, worker_days=2)  # M = 2: enough
    assert other.post(f"{BASE}/solve", headers=auth(ADMIN)).status_code == 202
    assert other.get(f"{BASE}/status", headers=auth(READ)).json()["history"]["enough"] is True


def test_status_shows_the_worker_its_solve_the_request_the_last_and_the_next_solve(
    make_client: MakeClient, registry: CityRegistry, any_store: Store
) -> None:
    client = make_client(store=any_store, tokens=WITH_ADMIN)
    k = target(registry)
    hz = registry.get(CITY).horizon
    now = time.time()
    solving = SolveProgress(int(k), "request", "req-7", now - 42.0, 60, 17, 5, 2, 0)
    live = beat(2.0, solving=solving, next_interval=int(k) + 1, next_due_at_s=now + 900.0, embedded=True)
    gone = WorkerBeat("box-2:9:def", now - 500.0, now - 900.0, "box-2", 9, False, 5.0)
    any_store.record_worker_beat(CITY, gone, 3600.0)
    any_store.record_worker_beat(CITY, live, 3600.0)
    any_store.enqueue_solve_request(CITY, SolveRequest("req-8", now - 3.0, "tok-…"))
    any_store.record_solve_failure(CITY, FleetRecord("failed", now - 60.0, int(k), reason="boom"), 10)
    r = client.get(f"{BASE}/status", headers=auth(READ))
    assert r.status_code == 200, r.text
    st = r.json()
    assert st["city"] == CITY and st["now"].endswith("+08:00")
    w = st["worker"]
    assert w["seen"] is True and w["hint"] is None and w["stale_after_s"] == 30.0
    assert 2.0 <= w["heartbeat_age_s"] < 10.0
    assert [(x["id"], x["live"], x["embedded"]) for x in w["workers"]] == [
        ("box-1:77:abc", True, True),
        ("box-2:9:def", False, False),
    ]
    s = st["solving"]
    assert (s["interval"], s["trigger"], s["request_id"], s["worker"]) == (
        hz.label(k),
        "request",
        "req-7",
        "box-1:77:abc",
    )
    assert (s["runs_total"], s["runs_done"], s["runs_cached"], s["runs_running"]) == (60, 17, 5, 2)
    assert 42.0 <= s["elapsed_s"] < 50.0
    assert st["pending_request"]["request_id"] == "req-8"
    assert st["last_solve"] == {
        "status": "failed",
        "computed_at": format_time(now - 60.0, hz.timezone),
        "interval": hz.label(k),
        "version": None,
        "reason": "boom",
        "request_id": None,
    }
    assert st["next_scheduled"]["interval"] == hz.label(k + 1)
    # a solve by a worker that is gone is not "in progress"
    any_store.record_worker_beat(CITY, beat(100.0, solving=solving), 3600.0)
    st = client.get(f"{BASE}/status", headers=auth(READ)).json()
    assert st["solving"] is None and st["worker"]["seen"] is False and st["next_scheduled"] is None


def test_metrics_expose_the_heartbeat_age(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store)
    text = client.get("/metrics").text
    assert f'sd_fleet_worker_heartbeat_age_seconds{{city="{CITY}"}} +Inf' in text
    any_store.record_worker_beat(CITY, beat(12.0), 3600.0)
    line = next(
        x for x in client.get("/metrics").text.splitlines() if x.startswith("sd_fleet_worker_heartbeat_age")
    )
    assert 12.0 <= float(line.rsplit(" ", 1)[1]) < 20.0
