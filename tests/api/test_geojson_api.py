"""GIS exports and stored epochs over HTTP, on both stores: the road network, the grid counts and an epoch's
routes as RFC 7946 GeoJSON (checked by tests/rfc7946.py and against the JSON endpoints), the stored decision
of a committed epoch, the epoch log, and the dashboard page."""

from __future__ import annotations

import datetime as dt
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.ports import Store
from services.dispatch import decide
from tests import rfc7946
from tests.api import payloads
from tests.api.conftest import READ, MakeClient, auth, fingerprint
from tests.api.fakes import CITY, N

GEO = "application/geo+json"
BASE = f"/v1/cities/{CITY}"


def geojson(client: TestClient, path: str, **params: str) -> dict[str, Any]:
    r = client.get(f"{BASE}/{path}", params=params, headers=auth(READ))
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == GEO
    doc: dict[str, Any] = r.json()
    assert rfc7946.problems(doc) == []
    return doc


def test_graph_geojson_is_the_graph(make_client: MakeClient) -> None:
    client = make_client()
    doc = geojson(client, "graph.geojson")
    graph = client.get(f"{BASE}/graph", headers=auth()).json()
    where = {n["id"]: [round(n["lon"], 6), round(n["lat"], 6)] for n in graph["nodes"]}
    feats = doc["features"]
    assert len(feats) == len(graph["edges"]) == 2 * 2 * N * (N - 1)
    for f, e in zip(feats, graph["edges"], strict=True):
        p = f["properties"]
        assert (p["u"], p["v"], p["length_m"], p["travel_time_s"]) == (
            e["u"], e["v"], e["length_m"], e["travel_time_s"],
        )  # fmt: skip
        assert f["geometry"] == {"type": "LineString", "coordinates": [where[e["u"]], where[e["v"]]]}
    assert [f["id"] for f in feats] == list(range(len(feats)))


def test_coverage_geojson_has_every_cell_and_the_counts_of_coverage(
    any_store: Store, make_client: MakeClient
) -> None:
    client = make_client(store=any_store)
    city = client.get(BASE, headers=auth()).json()
    n_cells = city["grid"]["n_cols"] * city["grid"]["n_rows"]
    empty = geojson(client, "coverage.geojson", interval="2026-11-23T08:00")
    assert len(empty["features"]) == n_cells
    assert not any(f["properties"]["sensed"] for f in empty["features"])
    assert sum(f["properties"]["weight"] > 0 for f in empty["features"]) == city["grid"]["n_cells_touched"]

    for i, minutes in enumerate((0, 4, 70)):
        r = client.post(f"{BASE}/epochs", json=payloads.epoch(f"e{i}", minutes), headers=auth())
        assert r.status_code == 200, r.text
    for label in ("2026-11-23T08:00", "2026-11-23T09:00", "2026-11-23T10:00"):
        cov = client.get(f"{BASE}/coverage", params={"interval": label}, headers=auth()).json()
        doc = geojson(client, "coverage.geojson", interval=label)
        assert (doc["city"], doc["interval"], doc["interval_key"]) == (CITY, label, cov["interval_key"])
        sensed = {
            (p["col"], p["row"]): p["lambda"] for f in doc["features"] if (p := f["properties"])["sensed"]
        }
        assert sensed == {tuple(c["cell"]): c["count"] for c in cov["cells"]}
        assert len(sensed) == cov["n_cells_covered"]
        assert all(f["properties"]["lambda"] == 0 for f in doc["features"] if not f["properties"]["sensed"])
    assert sensed == {}  # nothing at 10:00
    # an RFC 3339 time inside the interval names the same interval
    assert (
        geojson(client, "coverage.geojson", interval="2026-11-23T08:30:00+08:00")["interval"]
        == "2026-11-23T08:00"
    )


def test_coverage_geojson_needs_a_valid_interval(make_client: MakeClient) -> None:
    client = make_client()
    r = client.get(f"{BASE}/coverage.geojson", headers=auth())
    assert r.status_code == 422 and r.json()["error"] == "validation_error"
    assert r.json()["fields"][0]["loc"] == "interval"
    r = client.get(f"{BASE}/coverage.geojson", params={"interval": "2026-11-23T08:30"}, headers=auth())
    assert r.status_code == 422 and "not the start of an interval" in r.json()["detail"]
    r = client.get(
        "/v1/cities/atlantis/coverage.geojson", params={"interval": "2026-11-23T08:00"}, headers=auth()
    )
    assert r.status_code == 404 and r.json()["error"] == "unknown_city"


def test_epoch_log_and_stored_epochs(any_store: Store, make_client: MakeClient) -> None:
    client = make_client(store=any_store)
    log = client.get(f"{BASE}/epochs", headers=auth(READ)).json()
    assert log == {"city": CITY, "committed": 0, "last": None}
    posted = [
        client.post(f"{BASE}/epochs", json=payloads.epoch(f"e{i}", 4 * i), headers=auth()) for i in (1, 2)
    ]
    log = client.get(f"{BASE}/epochs", headers=auth(READ)).json()
    assert log == {
        "city": CITY,
        "committed": 2,
        "last": {"epoch_id": "e2", "time": "2026-11-23T08:08:00+08:00"},
    }
    before = fingerprint(any_store)
    for i, r in zip((1, 2), posted, strict=True):
        got = client.get(f"{BASE}/epochs/e{i}", headers=auth(READ))
        assert got.status_code == 200 and got.headers["content-type"] == "application/json"
        assert got.content == r.content  # the stored response, byte for byte
    missing = client.get(f"{BASE}/epochs/e9", headers=auth(READ))
    assert missing.status_code == 404
    assert missing.json() == {
        "error": "unknown_epoch",
        "detail": "no committed epoch 'e9' in 'tiny' (never posted, or older than the retention)",
        "fields": [],
    }
    assert (
        client.get(f"{BASE}/epochs/e9/routes.geojson", headers=auth(READ)).json()["error"] == "unknown_epoch"
    )
    assert fingerprint(any_store) == before  # reading changes nothing


@pytest.mark.parametrize("path", ["graph.geojson", "coverage.geojson?interval=2026-11-23T08:00", "epochs",
                                  "epochs/e1", "epochs/e1/routes.geojson"])  # fmt: skip
def test_the_exports_need_the_read_scope(make_client: MakeClient, path: str) -> None:
    client = make_client()
    r = client.get(f"{BASE}/{path}")
    assert r.status_code == 401 and r.json()["error"] == "unauthorized"
    r = client.get(f"{BASE}/{path}", headers=auth("tok-disp-00000001"))
    assert r.status_code == 403 and r.json()["error"] == "forbidden"


def test_routes_geojson_draws_the_decision(any_store: Store, make_client: MakeClient) -> None:
    """The real solver on the tiny lattice: riders matched and idle instrumented taxis sent to POIs."""
    client = make_client(store=any_store, decide=decide)
    open_tasks, body = payloads.both_kinds()
    assert client.post(f"{BASE}/tasks", json=open_tasks, headers=auth()).status_code == 200
    epoch = client.post(f"{BASE}/epochs", json=body, headers=auth()).json()
    assert epoch["rider_matches"] and epoch["task_assignments"]  # the case exercises both kinds

    graph = client.get(f"{BASE}/graph", headers=auth()).json()
    where = {n["id"]: [round(n["lon"], 6), round(n["lat"], 6)] for n in graph["nodes"]}
    doc = geojson(client, "epochs/e1/routes.geojson")
    assert (doc["city"], doc["epoch_id"], doc["time"]) == (CITY, "e1", epoch["time"])
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    n_riders, n_routes = len(epoch["rider_matches"]), len(epoch["task_assignments"])
    assert kinds[: n_riders + n_routes] == ["rider"] * n_riders + ["poi"] * n_routes
    for f, m in zip(doc["features"], epoch["rider_matches"], strict=False):
        p = f["properties"]
        assert (p["step"], p["taxi_id"], p["rider_id"], p["wait_s"]) == (
            m["step"],
            m["taxi_id"],
            m["rider_id"],
            m["wait_s"],
        )
        assert f["geometry"]["coordinates"] == [where[v] for v in m["path"]]
        assert p["depart_at"] == epoch["time"]
        pickup = dt.datetime.fromisoformat(p["pickup_at"]) - dt.datetime.fromisoformat(p["depart_at"])
        assert pickup.total_seconds() == pytest.approx(m["wait_s"], abs=1e-5)
        trip = dt.datetime.fromisoformat(p["dropoff_at"]) - dt.datetime.fromisoformat(p["pickup_at"])
        assert trip.total_seconds() == pytest.approx(m["trip_time_s"], abs=1e-5)
    routes = doc["features"][n_riders : n_riders + n_routes]
    for f, a in zip(routes, epoch["task_assignments"], strict=True):
        p = f["properties"]
        assert (p["step"], p["taxi_id"], p["task_id"], p["length_m"]) == (
            3,
            a["taxi_id"],
            a["task_id"],
            a["length_m"],
        )
        assert f["geometry"]["coordinates"] == [where[v] for v in a["path"]]
    # the tasks the epoch touched, as it left them: assigned ones at the end of their route, completed ones
    points = {f["properties"]["task_id"]: f for f in doc["features"] if f["properties"]["kind"] == "task"}
    assigned = {a["task_id"]: a for a in epoch["task_assignments"]}
    completed = {t["id"]: t for t in epoch["tasks_completed"]}
    assert set(points) == set(assigned) | set(completed)
    for task_id, f in points.items():
        p = f["properties"]
        if task_id in assigned:
            a = assigned[task_id]
            assert (p["status"], p["taxi_id"], p["mode"]) == ("assigned", a["taxi_id"], "active")
            assert f["geometry"]["coordinates"] == where[a["path"][-1]]
        else:
            assert (p["status"], p["completed_at"]) == ("completed", completed[task_id]["completed_at"])
            assert f["geometry"]["coordinates"] == where[completed[task_id]["node"]]


def test_the_dashboard_page_needs_no_token(make_client: MakeClient) -> None:
    client = make_client()
    page = client.get("/dashboard")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert '<script src="dashboard/assets/dashboard.js">' in page.text
    for asset, kind in (("dashboard.js", "javascript"), ("dashboard.css", "text/css")):
        r = client.get(f"/dashboard/assets/{asset}")
        assert r.status_code == 200 and kind in r.headers["content-type"] and len(r.content) > 1000
    missing = client.get("/dashboard/assets/nothing.js")
    assert missing.status_code == 404 and missing.json()["error"] == "not_found"


def test_the_graph_is_gzipped_for_clients_that_accept_it(make_client: MakeClient) -> None:
    client = make_client()
    url = f"{BASE}/graph.geojson"
    plain = client.get(url, headers=auth() | {"Accept-Encoding": "identity"})
    assert "content-encoding" not in plain.headers and plain.headers["vary"] == "Accept-Encoding"
    packed = client.get(url, headers=auth() | {"Accept-Encoding": "br, gzip;q=0.8"})
    assert packed.headers["content-encoding"] == "gzip" and packed.headers["content-type"] == GEO
    assert int(packed.headers["content-length"]) < len(plain.content) / 3
    assert packed.content == plain.content  # the client unpacked it to the same text
    refused = client.get(url, headers=auth() | {"Accept-Encoding": "gzip;q=0"})
    assert "content-encoding" not in refused.headers


def test_an_epoch_id_with_a_slash_is_read_back(make_client: MakeClient) -> None:
    client = make_client()
    posted = client.post(f"{BASE}/epochs", json=payloads.epoch("2026/11/23 08:00", 0), headers=auth())
    assert posted.status_code == 200
    got = client.get(f"{BASE}/epochs/2026%2F11%2F23%2008:00", headers=auth(READ))
    assert got.status_code == 200 and got.content == posted.content
    doc = geojson(client, "epochs/2026%2F11%2F23%2008:00/routes.geojson")
    assert doc["epoch_id"] == "2026/11/23 08:00"
    assert client.get(f"{BASE}/epochs", headers=auth(READ)).json()["last"]["epoch_id"] == "2026/11/23 08:00"
