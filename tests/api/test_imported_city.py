"""A city imported from CSV with the CLI is served by name, and every endpoint works on it."""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.adapters.memory_store import MemoryStore
from app.bootstrap import create_app
from app.entrypoints import cli
from app.settings import Settings

TOKEN = "import-token-0001"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def lattice_csv(folder: Path, n: int = 6, step_deg: float = 0.004) -> tuple[Path, Path]:
    """An n x n two-way lattice near Lyon (about 300 m x 450 m blocks), as nodes.csv and edges.csv."""
    nodes = folder / "nodes.csv"
    edges = folder / "edges.csv"
    lines = ["id,lon,lat"]
    for r in range(n):
        for c in range(n):
            lines.append(f"{100 + r * n + c},{4.80 + c * step_deg:.6f},{45.74 + r * step_deg:.6f}")
    nodes.write_text("\n".join(lines) + "\n")
    rows = ["u,v,length_m,speed_kmh"]
    for r in range(n):
        for c in range(n):
            a = 100 + r * n + c
            if c + 1 < n:
                rows += [f"{a},{a + 1},311.0,30", f"{a + 1},{a},311.0,30"]
            if r + 1 < n:
                rows += [f"{a},{a + n},445.0,30", f"{a + n},{a},445.0,30"]
    edges.write_text("\n".join(rows) + "\n")
    return nodes, edges


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    nodes, edges = lattice_csv(tmp_path)
    out = tmp_path / "cities"
    rc = cli.main(
        [
            "import-city",
            "lyon",
            "--nodes",
            str(nodes),
            "--edges",
            str(edges),
            "--out",
            str(out),
            "--timezone",
            "Europe/Paris",
        ]
    )
    assert rc == 0
    app = create_app(
        Settings().with_values(tokens={TOKEN: ["read", "dispatch"]}, cities_dir=out), store=MemoryStore()
    )
    with TestClient(app) as c:
        yield c


def test_every_endpoint_on_an_imported_city(client: TestClient) -> None:
    names = [c["name"] for c in client.get("/v1/cities", headers=AUTH).json()["cities"]]
    assert "lyon" in names and "chengdu" in names
    info = client.get("/v1/cities/lyon", headers=AUTH).json()
    assert info["network"]["nodes"] == 36 and info["network"]["edges"] == 120
    assert info["grid"]["crs"] == "EPSG:32631" and info["grid"]["cell_m"] == 1000.0
    graph = client.get("/v1/cities/lyon/graph", headers=AUTH).json()
    assert len(graph["nodes"]) == 36 and len(graph["edges"]) == 120
    # 311 m at 30 km/h
    assert {round(e["travel_time_s"], 3) for e in graph["edges"]} == {
        round(311 / (30 / 3.6), 3),
        round(445 / (30 / 3.6), 3),
    }

    tz = dt.timezone(dt.timedelta(hours=1))
    now = dt.datetime(2026, 11, 23, 9, 0, tzinfo=tz)
    r = client.post(
        "/v1/cities/lyon/tasks",
        headers=AUTH,
        json=[
            {
                "id": "poi",
                "location": {"node": 135},
                "scheduled_at": (now - dt.timedelta(minutes=5)).isoformat(),
            }
        ],
    )
    assert r.status_code in (200, 201), r.text
    epoch: dict[str, Any] = {
        "epoch_id": "e1",
        "time": now.isoformat(),
        "riders": [
            {
                "id": "r",
                "origin": {"node": 107},
                "destination": {"lon": 4.816, "lat": 45.756},
                "requested_at": (now - dt.timedelta(seconds=30)).isoformat(),
            }
        ],
        "taxis": [
            {"id": "i1", "location": {"node": 100}, "instrumented": True, "status": "vacant"},
            {"id": "i2", "location": {"node": 130}, "instrumented": True, "status": "vacant"},
            {"id": "o1", "location": {"node": 101}, "instrumented": False, "status": "vacant"},
        ],
    }
    r = client.post("/v1/cities/lyon/epochs", headers=AUTH, json=epoch)
    assert r.status_code == 200, r.text
    body = r.json()
    (m,) = body["rider_matches"]
    assert m["step"] == 1 and m["taxi_id"] == "i1" and m["path"][0] == 100 and m["path"][-1] == 128
    (a,) = body["task_assignments"]
    assert a["taxi_id"] == "i2" and a["task_id"] == "poi" and a["path"][-1] == 135
    cov = client.get("/v1/cities/lyon/coverage", headers=AUTH).json()
    assert cov["interval"] == "2026-11-23T09:00" and cov["coverage_rate"] > 0
    tasks = client.get("/v1/cities/lyon/tasks", headers=AUTH).json()
    (t,) = tasks["tasks"]
    assert t["status"] == "assigned" and t["taxi_id"] == "i2" and t["mode"] == "active"
    # a location outside the imported city is an input error naming the field
    epoch["epoch_id"] = "e2"
    epoch["taxis"][0]["location"] = {"lon": 104.07, "lat": 30.66}
    r = client.post("/v1/cities/lyon/epochs", headers=AUTH, json=epoch)
    assert r.status_code == 422 and r.json()["fields"][0]["loc"] == "taxis[0].location"
