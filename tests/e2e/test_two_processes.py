"""Two real API processes on one real Redis, fed one city's epochs, against one in-process service.

The epochs go alternately to process A and process B (as a load balancer would send them); one epoch is
also retried on the other process, and one is posted to both at the same moment. At the end both the
decisions and the grid counts must equal those of a single service that saw the same epochs once.
"""

from __future__ import annotations

import datetime as dt
import threading
import uuid
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.adapters.memory_store import MemoryStore
from app.bootstrap import create_app
from app.settings import Settings
from services.citydata import load_city
from tests.e2e.service import ROOT, start_service, stop, wait_ready

TOKEN = "e2e-token-0000001"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CITY = "chengdu"


@pytest.fixture
def two_services(redis_url: str) -> Iterator[tuple[str, str]]:
    prefix = f"e2e{uuid.uuid4().hex[:10]}"
    procs = [start_service(redis_url, prefix, {TOKEN: ["read", "dispatch"]}) for _ in range(2)]
    try:
        for proc, url in procs:
            wait_ready(url, proc)
        yield procs[0][1], procs[1][1]
    finally:
        for proc, _ in procs:
            stop(proc)


def _epochs(n: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Seeded epochs on Chengdu: a fixed fleet moving to random nodes, a few riders each time."""
    city = load_city(ROOT / "app" / "data" / "cities" / CITY)
    ids = city.network.node_ids
    rng = np.random.default_rng(7)
    tz = dt.timezone(dt.timedelta(hours=8))
    t0 = dt.datetime(2026, 11, 23, 8, 50, tzinfo=tz)  # crosses into the 09:00 interval

    def node() -> dict[str, int]:
        return {"node": int(ids[rng.integers(len(ids))])}

    tasks = [
        {
            "id": f"poi{i}",
            "location": node(),
            "scheduled_at": (t0 + dt.timedelta(seconds=300 * i)).isoformat(),
        }
        for i in range(6)
    ]
    out = []
    for e in range(n):
        now = t0 + dt.timedelta(seconds=200 * e)
        riders = [
            {
                "id": f"r{e}-{j}",
                "origin": node(),
                "destination": node(),
                "requested_at": (now - dt.timedelta(seconds=20)).isoformat(),
            }
            for j in range(int(rng.integers(3, 8)))
        ]
        taxis = [
            {"id": f"t{k}", "location": node(), "instrumented": k < 12, "status": "vacant"} for k in range(24)
        ]
        out.append({"epoch_id": f"e{e:03d}", "time": now.isoformat(), "riders": riders, "taxis": taxis})
    return out, tasks


def _decision(body: dict[str, Any]) -> dict[str, Any]:
    keep = ("rider_matches", "task_assignments", "tasks_completed", "unmatched_rider_ids")
    return {k: body[k] for k in keep}


def _coverage(client: Any, labels: list[str]) -> dict[str, Any]:
    out = {}
    for label in labels:
        r = client.get(f"/v1/cities/{CITY}/coverage", params={"interval": label}, headers=AUTH)
        assert r.status_code == 200, r.text
        body = r.json()
        out[label] = sorted((tuple(c["cell"]), c["count"]) for c in body["cells"])
    return out


@pytest.mark.redis
def test_two_processes_count_like_one(two_services: tuple[str, str]) -> None:
    a, b = two_services
    epochs, tasks = _epochs(8)
    with httpx.Client(timeout=120) as http:
        assert http.post(f"{a}/v1/cities/{CITY}/tasks", json=tasks, headers=AUTH).status_code in (200, 201)
        assert http.post(f"{b}/v1/cities/{CITY}/tasks", json=tasks, headers=AUTH).status_code in (200, 201)
        got = []
        for i, body in enumerate(epochs[:-1]):
            url = (a, b)[i % 2]
            r = http.post(f"{url}/v1/cities/{CITY}/epochs", json=body, headers=AUTH)
            assert r.status_code == 200, r.text
            got.append(r.json())
            if i == 3:  # a client retry that lands on the other process: the stored answer, nothing recounted
                again = http.post(f"{(b, a)[i % 2]}/v1/cities/{CITY}/epochs", json=body, headers=AUTH)
                assert again.status_code == 200 and again.headers.get("Idempotent-Replayed") == "true"
                assert again.json() == r.json()
        # the last epoch posted to both processes at the same moment
        results: list[httpx.Response] = []

        def post(url: str) -> None:
            with httpx.Client(timeout=120) as c:
                results.append(c.post(f"{url}/v1/cities/{CITY}/epochs", json=epochs[-1], headers=AUTH))

        threads = [threading.Thread(target=post, args=(u,)) for u in (a, b)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert [r.status_code for r in results] == [200, 200]
        assert results[0].json() == results[1].json()
        assert sorted(r.headers.get("Idempotent-Replayed", "false") for r in results) == ["false", "true"]
        got.append(results[0].json())
        labels = ["2026-11-23T08:00", "2026-11-23T09:00", "2026-11-23T10:00"]
        assert {g["stats"]["interval"] for g in got} == set(labels[:2])
        with httpx.Client(base_url=a, timeout=60) as ca:
            two = _coverage(ca, labels)

    # the same epochs, once each, to one in-process service
    one_app = create_app(Settings().with_values(tokens={TOKEN: ["read", "dispatch"]}), store=MemoryStore())
    with TestClient(one_app) as one:
        assert one.post(f"/v1/cities/{CITY}/tasks", json=tasks, headers=AUTH).status_code in (200, 201)
        want = []
        for body in epochs:
            r = one.post(f"/v1/cities/{CITY}/epochs", json=body, headers=AUTH)
            assert r.status_code == 200, r.text
            want.append(r.json())
        single = _coverage(one, labels)
    assert [_decision(g) for g in got] == [_decision(w) for w in want]
    assert two == single
    assert sum(n for cells in single.values() for _, n in cells) > 0
