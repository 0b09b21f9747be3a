"""A committed epoch read back is its response: the document the store keeps (through the store port and
through ``GET /epochs/{id}``) equals the POST's response byte for byte, and parsed back into core types it
keeps every field the response shows, the routes' kappa included; on each store."""

from __future__ import annotations

import math

from app.adapters.city_registry import CityRegistry
from app.ports import Store
from app.usecases.epoch_record import read_epoch
from services.dispatch import decide
from tests.api import payloads
from tests.api.conftest import READ, MakeClient, auth
from tests.api.fakes import CITY

BASE = f"/v1/cities/{CITY}"


def test_the_stored_epoch_is_the_response(
    any_store: Store, make_client: MakeClient, registry: CityRegistry
) -> None:
    client = make_client(store=any_store, decide=decide)
    open_tasks, body = payloads.both_kinds()
    assert client.post(f"{BASE}/tasks", json=open_tasks, headers=auth()).status_code == 200
    posted = client.post(f"{BASE}/epochs", json=body, headers=auth())
    assert posted.status_code == 200, posted.text
    response = posted.json()
    assert response["rider_matches"] and response["task_assignments"]  # the case has both kinds

    stored = any_store.get_epoch(CITY, "e1")
    assert stored is not None and stored.response_json == posted.text
    got = client.get(f"{BASE}/epochs/e1", headers=auth(READ))
    assert got.status_code == 200 and got.text == posted.text

    city = registry.get(CITY)
    decision = read_epoch(city, stored.response_json)
    assert decision.epoch_id == response["epoch_id"] == "e1"
    ids = city.network.node_ids
    for m, doc in zip(decision.rider_matches, response["rider_matches"], strict=True):
        assert [int(ids[v]) for v in m.path] == doc["path"]
        fields = (
            "step",
            "taxi_id",
            "rider_id",
            "pickup_m",
            "wait_s",
            "trip_m",
            "trip_time_s",
            "sensing_gain",
        )
        assert [getattr(m, f) for f in fields] == [doc[f] for f in fields]
        assert [list(c) for c in m.cells] == doc["cells"]
    for a, doc in zip(decision.task_assignments, response["task_assignments"], strict=True):
        assert [int(ids[v]) for v in a.path] == doc["path"]
        route_fields = (
            "taxi_id",
            "task_id",
            "length_m",
            "travel_time_s",
            "sensing_gain",
            "efficiency",
            "cost_cny",
        )
        assert [getattr(a, f) for f in route_fields] == [doc[f] for f in route_fields]
        assert [list(c) for c in a.cells] == doc["cells"]
        assert math.isfinite(a.kappa) and a.kappa == doc["kappa"] and a.kappa in city.params.kappas
    assert [t.id for t in decision.tasks_completed] == [t["id"] for t in response["tasks_completed"]]

    again = client.post(f"{BASE}/epochs", json=body, headers=auth())
    assert again.headers.get("Idempotent-Replayed") == "true" and again.text == posted.text
