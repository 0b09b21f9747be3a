"""Read routes: cities, graph, tasks and coverage."""

from __future__ import annotations

import math

from app.adapters import MemoryStore
from services.model import IntervalKey
from tests.api import payloads
from tests.api.conftest import CITY, MakeClient, auth
from tests.api.fakes import NODE0, N, node_id


def test_cities(make_client: MakeClient) -> None:
    client = make_client()
    (city,) = client.get("/v1/cities", headers=auth()).json()["cities"]
    assert city == client.get(f"/v1/cities/{CITY}", headers=auth()).json()
    assert city["name"] == CITY
    assert city["network"] == {"nodes": N * N, "edges": 2 * 2 * N * (N - 1), "road_km": 32.0}
    lon0, lat0, lon1, lat1 = city["bbox"]
    assert lon0 < lon1 and lat0 < lat1 and math.isclose(lon0, 104.06)
    grid = city["grid"]
    assert set(grid) == {"crs", "origin", "cell_m", "n_cols", "n_rows", "n_cells_touched"}
    assert grid["crs"] == "EPSG:32648" and grid["cell_m"] == 1000.0
    assert grid["origin"][0] % 1000 == 0 and grid["n_cells_touched"] <= grid["n_cols"] * grid["n_rows"]
    assert city["horizon"] == {
        "timezone": "Asia/Shanghai",
        "start": "08:00:00",
        "interval_s": 3600,
        "n_intervals": 4,
        "epoch_s": 200,
    }
    assert city["params"]["radius_m"] == 2000.0 and city["params"]["kappas"] == [0.0, 0.3, 0.6, 0.9]
    assert city["source"] == "hand-built test lattice"


def test_graph(make_client: MakeClient) -> None:
    graph = make_client().get(f"/v1/cities/{CITY}/graph", headers=auth()).json()
    ids = {n["id"] for n in graph["nodes"]}
    assert ids == set(range(NODE0, NODE0 + N * N))
    assert set(graph["nodes"][0]) == {"id", "lon", "lat", "cell"}
    assert all(len(n["cell"]) == 2 for n in graph["nodes"])
    edge = next(e for e in graph["edges"] if (e["u"], e["v"]) == (node_id(0, 0), node_id(1, 0)))
    assert edge["length_m"] == 400.0 and math.isclose(edge["travel_time_s"], 400 / (35 / 3.6))
    assert all(e["u"] in ids and e["v"] in ids for e in graph["edges"])
    # node cells agree with the cells of the matches' G-routes
    cells = {n["id"]: tuple(n["cell"]) for n in graph["nodes"]}
    assert cells[node_id(0, 0)] == (0, 0)


def test_tasks_listing(make_client: MakeClient) -> None:
    client = make_client()
    client.post(f"/v1/cities/{CITY}/tasks", json=payloads.tasks(), headers=auth())
    tasks = client.get(f"/v1/cities/{CITY}/tasks", headers=auth()).json()["tasks"]
    assert [t["id"] for t in tasks] == ["poi-a", "poi-b"]
    assert tasks[0] == {
        "id": "poi-a",
        "node": node_id(0, 0),
        "status": "pending",
        "scheduled_at": "2026-11-23T07:50:00+08:00",
        "completed_at": None,
        "taxi_id": None,
        "mode": None,
    }
    assert tasks[1]["node"] == node_id(4, 2)  # lon/lat snapped


def test_coverage(make_client: MakeClient) -> None:
    store = MemoryStore()
    client = make_client(store=store)
    url = f"/v1/cities/{CITY}/coverage"
    r = client.get(url, headers=auth())
    assert r.status_code == 404 and r.json()["error"] == "no_data"
    r = client.get(url, params={"interval": "2026-11-23T09:00"}, headers=auth())
    assert r.status_code == 200 and r.json()["cells"] == [] and r.json()["coverage_rate"] == 0.0

    client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch("e1", 5), headers=auth())
    cov = client.get(url, headers=auth()).json()
    assert cov["interval"] == "2026-11-23T08:00" and cov["in_horizon"] is True
    assert sorted(tuple(c["cell"]) for c in cov["cells"]) == [
        (0, 0),
        (2, 1),
    ]  # t0's path 1005 -> 1000 -> 1024
    assert all(c["count"] == 1 for c in cov["cells"])
    n = cov["n_cells_touched"]
    assert cov["n_cells_covered"] == 2 and math.isclose(cov["coverage_rate"], 2 / n)
    # Gamma = mu_t * sum_g s_g * Lambda^rho with uniform weights: (1/4) * 2 * (1/n) * 1
    assert math.isclose(cov["gamma_so_far"], 0.25 * 2 / n)
    assert store.interval_counts(CITY, IntervalKey(cov["interval_key"]))
    for q in ("2026-11-23T08:00", "2026-11-23T08:59:59+08:00", "2026-11-23T00:30:00Z"):
        assert client.get(url, params={"interval": q}, headers=auth()).json() == cov
    other = client.get(url, params={"interval": "2026-11-23T10:00"}, headers=auth()).json()
    assert other["cells"] == [] and math.isclose(other["gamma_so_far"], cov["gamma_so_far"])
