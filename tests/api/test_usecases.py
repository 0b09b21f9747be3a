"""The use cases on the core's types, without HTTP: the epoch flow's renderer and reader seams, coverage,
task conflicts, committed epochs read back; and the canonical body hash every committed epoch is stored
with."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from app.adapters import MemoryStore
from app.adapters.city_registry import CityRegistry
from app.errors import EpochConflict, NoData, TaskConflict, UnknownEpoch
from app.schemas.decision import EpochIn, body_hash
from app.usecases import EpochCommand, EpochResult, StoredDecision, UseCases
from services.city import City
from services.model import (
    IntervalKey,
    Rider,
    RiderId,
    Snapshot,
    Task,
    TaskAssignment,
    TaskId,
    Taxi,
    TaxiId,
)
from tests.api.fakes import CITY, T0, FakeDecide, node_id


class Renderer:
    """Records what it is asked to render; the document is a small JSON naming the epoch."""

    def __init__(self) -> None:
        self.results: list[EpochResult] = []

    def __call__(self, result: EpochResult) -> str:
        self.results.append(result)
        return json.dumps({"rendered": result.epoch.snapshot.epoch_id, "n": len(self.results)})


class Reader:
    """Reads the renderer's documents back: a decision with one POI route for every task id in ``routes``."""

    def __init__(self, routes: dict[str, list[TaskId]]) -> None:
        self.routes = routes
        self.read: list[str] = []

    def __call__(self, city: City, response_json: str) -> StoredDecision:
        epoch_id = json.loads(response_json)["rendered"]
        self.read.append(epoch_id)
        assignments = tuple(
            TaskAssignment(TaxiId(f"t-{t}"), t, (0, 1), ((0, 0),), 400.0, 41.1, 0.5, 0.01, 0.6, 0.0)
            for t in self.routes.get(epoch_id, [])
        )
        return StoredDecision(epoch_id, T0.timestamp(), (), assignments, ())


def service(registry: CityRegistry, reader: Reader | None = None) -> tuple[UseCases, MemoryStore, Renderer]:
    store, render = MemoryStore(), Renderer()
    read = reader or Reader({})
    return UseCases.over(registry, store, FakeDecide(), render_epoch=render, read_epoch=read), store, render


def command(registry: CityRegistry, epoch_id: str, minutes: float, digest: str = "h1") -> EpochCommand:
    """An epoch at T0 + minutes in node indices: one rider, an instrumented vacant taxi."""
    index = registry.get(CITY).network.index_of
    time_s = T0.timestamp() + 60.0 * minutes
    rider = Rider(RiderId("r1"), index(node_id(0, 0)), index(node_id(4, 4)), time_s - 30.0)
    taxi = Taxi(TaxiId("t0"), index(node_id(0, 1)), instrumented=True, vacant=True)
    return EpochCommand(Snapshot(epoch_id, time_s, (rider,), (taxi,)), digest, "as posted")


def test_an_epoch_is_rendered_once_and_replayed_verbatim(registry: CityRegistry) -> None:
    uc, store, render = service(registry)
    first = uc.epochs.submit_epoch(registry.get(CITY), command(registry, "e1", 0.0))
    assert not first.replayed and first.matches_by_step == {1: 1, 2: 0} and first.attempts == 1
    assert first.response_json == '{"rendered": "e1", "n": 1}'
    stored = store.get_epoch(CITY, "e1")
    assert stored is not None and stored.response_json == first.response_json and stored.body_hash == "h1"
    (result,) = render.results
    hz = registry.get(CITY).horizon
    assert result.interval == hz.interval_of(T0.timestamp()) and result.attempts == 1
    assert result.epoch.time_text == "as posted" and len(result.decision.rider_matches) == 1
    assert result.gamma_after > result.gamma_before == 0.0  # the taxi's cells are the first counted

    again = uc.epochs.submit_epoch(registry.get(CITY), command(registry, "e1", 0.0))
    assert again.replayed and again.response_json == first.response_json and len(render.results) == 1
    with pytest.raises(EpochConflict):
        uc.epochs.submit_epoch(registry.get(CITY), command(registry, "e1", 0.0, digest="h2"))


def test_coverage_of_the_last_epoch_and_of_a_given_interval(registry: CityRegistry) -> None:
    uc, store, _ = service(registry)
    with pytest.raises(NoData):
        uc.coverage.coverage(CITY, None)
    uc.epochs.submit_epoch(registry.get(CITY), command(registry, "e1", 0.0))
    cov = uc.coverage.coverage(CITY, None)
    k = registry.get(CITY).horizon.interval_of(T0.timestamp())
    assert cov.interval == k and cov.city.name == CITY
    counted = store.interval_counts(CITY, k)
    assert {int(c): int(n) for c, n in enumerate(cov.counts) if n} == counted and counted
    assert cov.coverage_rate == len(counted) / cov.city.n_cells_touched
    later = uc.coverage.coverage(CITY, IntervalKey(k + 1))
    assert not np.any(later.counts) and later.gamma_so_far == cov.gamma_so_far


def test_task_conflicts_name_their_positions(registry: CityRegistry) -> None:
    uc, _, _ = service(registry)
    node = registry.get(CITY).network.index_of(node_id(2, 2))
    a, b = Task(TaskId("a"), node, T0.timestamp()), Task(TaskId("b"), node, T0.timestamp())
    assert uc.tasks.put_tasks(registry.get(CITY), [a]).created == ["a"]
    moved = Task(TaskId("a"), node, T0.timestamp() + 60.0)
    with pytest.raises(TaskConflict) as err:
        uc.tasks.put_tasks(registry.get(CITY), [b, moved])
    assert [(f.loc, f.msg) for f in err.value.fields] == [
        ("[1].id", "task 'a' exists with different content")
    ]
    assert [t.id for t in uc.tasks.list_tasks(CITY)[1]] == ["a"]  # nothing written


def test_body_hash_is_the_sha256_of_the_canonical_json() -> None:
    """Stored with every committed epoch and compared on every replay: this definition must not drift (a
    change would answer replays of epochs committed before with 409)."""
    body = EpochIn.model_validate(
        {
            "time": "2026-11-23T00:00:00Z",
            "epoch_id": "e1",
            "riders": [
                {
                    "id": "r1",
                    "origin": {"node": 1000},
                    "destination": {"lon": 104.06, "lat": 30.66},
                    "requested_at": "2026-11-23T07:59:30.5+08:00",
                }
            ],
            "taxis": [{"id": "t0", "location": {"node": 1005}, "instrumented": True, "status": "vacant"}],
        }
    )
    canonical = (
        '{"epoch_id":"e1","riders":[{"destination":{"lat":30.66,"lon":104.06,"node":null},"id":"r1",'
        '"origin":{"lat":null,"lon":null,"node":1000},"requested_at":"2026-11-23T07:59:30.500000+08:00"}],'
        '"taxis":[{"id":"t0","instrumented":true,"location":{"lat":null,"lon":null,"node":1005},'
        '"status":"vacant"}],"time":"2026-11-23T00:00:00Z"}'
    )
    assert body_hash(body) == hashlib.sha256(canonical.encode()).hexdigest()


def test_committed_epochs_are_read_back_through_the_reader(registry: CityRegistry) -> None:
    reader = Reader({"e2": [TaskId("a"), TaskId("ghost")]})
    uc, store, _ = service(registry, reader)
    log = uc.epochs.epoch_log(CITY)
    assert (log.committed, log.last_epoch_id, log.last_epoch_time_s) == (0, None, None)
    store.put_tasks(CITY, [Task(TaskId("a"), 3, T0.timestamp() - 60.0)])
    uc.epochs.submit_epoch(registry.get(CITY), command(registry, "e1", 0))
    uc.epochs.submit_epoch(registry.get(CITY), command(registry, "e2", 4))
    log = uc.epochs.epoch_log(CITY)
    assert (log.committed, log.last_epoch_id, log.last_epoch_time_s) == (2, "e2", T0.timestamp() + 240.0)
    assert json.loads(uc.epochs.stored_epoch(CITY, "e1").response_json) == {"rendered": "e1", "n": 1}
    with pytest.raises(UnknownEpoch):
        uc.epochs.stored_epoch(CITY, "e3")
    assert reader.read == []  # the stored document is served as it is, not read back

    routes = uc.epochs.epoch_routes(CITY, "e2")
    assert reader.read == ["e2"] and routes.city is registry.get(CITY)
    a, ghost = routes.tasks
    # the registered task as the epoch left it: assigned to the route's taxi, reached at the route's end
    assert (a.id, a.node, a.scheduled_at_s) == ("a", 3, T0.timestamp() - 60.0)
    assert (a.status, a.taxi_id, a.mode) == ("assigned", "t-a", "active")
    assert a.completed_at_s == T0.timestamp() + 41.1
    # a task the store does not know keeps its POI (the route's end) and an unknown scheduled time
    assert (ghost.node, ghost.status) == (1, "assigned") and np.isnan(ghost.scheduled_at_s)
