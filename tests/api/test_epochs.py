"""Exactly-once epochs over HTTP: commit, replay, conflicts, stale epochs, retries; on both stores."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from typing import Any

import pytest

from app.adapters import MemoryStore
from app.ports import CityState, CommitResult, EpochCommit, Store
from services.model import IntervalKey, TaxiId
from tests.api import payloads
from tests.api.conftest import CITY, MakeClient, auth, fingerprint
from tests.api.fakes import FakeDecide, node_id

URL = f"/v1/cities/{CITY}/epochs"


def test_full_epoch_commits_counts_and_tasks(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store)
    assert client.post(f"/v1/cities/{CITY}/tasks", json=payloads.tasks(), headers=auth()).status_code == 200
    r = client.post(URL, json=payloads.epoch(), headers=auth())
    assert r.status_code == 200, r.text
    assert "Idempotent-Replayed" not in r.headers
    body = r.json()
    assert set(body) == {
        "epoch_id",
        "time",
        "rider_matches",
        "task_assignments",
        "tasks_completed",
        "unmatched_rider_ids",
        "expired_rider_ids",
        "stats",
    }
    assert body["epoch_id"] == "e1"
    m1, m2 = body["rider_matches"]
    assert (m1["step"], m1["taxi_id"], m1["rider_id"]) == (1, "t0", "r1")
    assert m1["path"] == [node_id(0, 1), node_id(0, 0), node_id(4, 4)]  # external ids
    assert (m2["step"], m2["taxi_id"], m2["rider_id"]) == (2, "t1", "r2")
    assert m2["path"][1] == node_id(3, 3)  # lon/lat snapped to the nearest node
    assert [t["id"] for t in body["tasks_completed"]] == ["poi-a"]
    assert body["tasks_completed"][0]["mode"] == "passive"
    stats = body["stats"]
    assert stats["step1_matches"] == 1 and stats["step2_matches"] == 1
    assert stats["interval"] == "2026-11-23T08:00" and stats["n_candidates"] == 2
    assert "solve_ms" in stats

    state = any_store.load_state(CITY, any_store.list_intervals(CITY), [TaxiId("t0")])
    assert state.version == 1 and state.last_epoch_id == "e1"
    assert sum(sum(c.values()) for c in state.counts.values()) == 2  # t0 crossed two cells
    tasks = {t["id"]: t for t in client.get(f"/v1/cities/{CITY}/tasks", headers=auth()).json()["tasks"]}
    assert tasks["poi-a"]["status"] == "completed" and tasks["poi-a"]["taxi_id"] == "t0"
    assert tasks["poi-b"]["status"] == "pending"


def test_replay_returns_stored_response_and_changes_nothing(
    make_client: MakeClient, any_store: Store
) -> None:
    decide = FakeDecide()
    client = make_client(store=any_store, decide=decide)
    first = client.post(URL, json=payloads.epoch(), headers=auth())
    before = fingerprint(any_store)
    again = client.post(URL, json=payloads.epoch(), headers=auth())
    assert again.status_code == 200
    assert again.headers["Idempotent-Replayed"] == "true"
    assert again.content == first.content
    assert fingerprint(any_store) == before
    assert len(decide.calls) == 1  # not solved again


def test_same_id_different_body_is_409(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store)
    client.post(URL, json=payloads.epoch(), headers=auth())
    before = fingerprint(any_store)
    changed = payloads.epoch()
    changed["taxis"][1]["status"] = "busy"
    r = client.post(URL, json=changed, headers=auth())
    assert r.status_code == 409
    assert r.json()["error"] == "epoch_conflict"
    assert r.json()["fields"][0]["loc"] == "epoch_id"
    assert fingerprint(any_store) == before


def test_stale_epoch_is_409(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store)
    assert client.post(URL, json=payloads.epoch("e2", 10), headers=auth()).status_code == 200
    before = fingerprint(any_store)
    r = client.post(URL, json=payloads.epoch("e1", 5), headers=auth())
    assert r.status_code == 409
    assert r.json()["error"] == "stale_epoch" and r.json()["fields"][0]["loc"] == "time"
    assert fingerprint(any_store) == before
    # the same time as the last epoch is not stale
    assert client.post(URL, json=payloads.epoch("e3", 10), headers=auth()).status_code == 200


def test_visits_counted_once_per_taxi_and_interval(make_client: MakeClient, any_store: Store) -> None:
    client = make_client(store=any_store)
    client.post(URL, json=payloads.epoch("e1", 0), headers=auth())
    client.post(URL, json=payloads.epoch("e2", 3.33), headers=auth())  # same interval, same taxi, same cells
    counts = any_store.interval_counts(CITY, any_store.list_intervals(CITY)[0])
    assert sorted(counts.values()) == [1, 1]


def test_loads_epoch_interval_next_two_and_the_days_horizon(make_client: MakeClient) -> None:
    decide = FakeDecide()
    client = make_client(decide=decide)
    r = client.post(URL, json=payloads.epoch("e1", 0), headers=auth())
    k = r.json()["stats"]["interval_key"]  # 08:00, the first of four
    assert decide.calls[0]["intervals"] == [k, k + 1, k + 2, k + 3]
    r = client.post(URL, json=payloads.epoch("e2", 190), headers=auth())  # 11:10, the last of four
    k = r.json()["stats"]["interval_key"]
    assert decide.calls[1]["intervals"] == [k - 3, k - 2, k - 1, k, k + 1, k + 2]


def test_gamma_in_stats(make_client: MakeClient) -> None:
    client = make_client()
    stats = client.post(URL, json=payloads.epoch("e1", 0), headers=auth()).json()["stats"]
    cov = client.get(f"/v1/cities/{CITY}/coverage", headers=auth()).json()
    assert stats["gamma"] == pytest.approx(cov["gamma_so_far"]) and stats["gamma"] > 0
    assert stats["gamma_gain"] == pytest.approx(stats["gamma"])  # from zero
    stats = client.post(URL, json=payloads.epoch("e2", 5), headers=auth()).json()["stats"]
    assert stats["gamma_gain"] == 0.0  # same taxi, same cells, same interval


def test_reloads_and_solves_again_when_decision_reaches_further(make_client: MakeClient) -> None:
    store = MemoryStore()
    decide = FakeDecide(extra_intervals=[5])
    client = make_client(store=store, decide=decide)
    r = client.post(URL, json=payloads.epoch(), headers=auth())
    assert r.status_code == 200
    k = r.json()["stats"]["interval_key"]
    assert [c["intervals"] for c in decide.calls] == [
        [k, k + 1, k + 2, k + 3],
        [k, k + 1, k + 2, k + 3, k + 5],
    ]
    assert fingerprint(store)[0] == 1


class RacingStore:
    """A MemoryStore on which another process commits an epoch between our load and our commit,
    ``races`` times (or forever)."""

    def __init__(self, races: int | None) -> None:
        self.inner = MemoryStore()
        self.races = races
        self.commits = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def load_state(
        self,
        city: str,
        intervals: Sequence[IntervalKey],
        taxi_ids: Sequence[TaxiId],
        *,
        visits_from: IntervalKey | None = None,
    ) -> CityState:
        state = self.inner.load_state(city, intervals, taxi_ids, visits_from=visits_from)
        if self.races is None or self.races > 0:
            if self.races is not None:
                self.races -= 1
            other = EpochCommit(f"other-{self.commits}", "h", 0.0, state.version, (), (), "{}")
            assert self.inner.commit_epoch(city, other).status == "committed"
        return state

    def commit_epoch(self, city: str, commit: EpochCommit) -> CommitResult:
        self.commits += 1
        return self.inner.commit_epoch(city, commit)


def test_version_mismatch_solves_again(make_client: MakeClient) -> None:
    store = RacingStore(races=2)
    decide = FakeDecide()
    client = make_client(store=store, decide=decide)
    r = client.post(URL, json=payloads.epoch("e1", 0), headers=auth())
    assert r.status_code == 200, r.text
    assert len(decide.calls) == 3 and r.json()["stats"]["attempts"] == 3
    assert "sd_commit_retries_total 2.0" in client.get("/metrics").text


def test_endless_version_mismatch_is_503_busy(make_client: MakeClient) -> None:
    store = RacingStore(races=None)
    decide = FakeDecide()
    client = make_client(store=store, decide=decide, commit_attempts=8)
    r = client.post(URL, json=payloads.epoch("e1", 0), headers=auth())
    assert r.status_code == 503
    assert r.json()["error"] == "busy"
    assert len(decide.calls) == 8
    assert store.inner.get_epoch(CITY, "e1") is None


def test_duplicate_at_commit_is_a_replay(make_client: MakeClient) -> None:
    """Two identical posts racing: the loser's commit finds the winner's record and replays it."""
    store = MemoryStore()
    decide = FakeDecide()
    client = make_client(store=store, decide=decide)
    first = client.post(URL, json=payloads.epoch(), headers=auth())

    class Late:
        def __getattr__(self, name: str) -> Any:
            return getattr(store, name)

        def get_epoch(self, city: str, epoch_id: str) -> None:
            return None  # as if the winner had not committed yet when we looked

    late = make_client(store=Late(), decide=FakeDecide())
    r = late.post(URL, json=payloads.epoch(), headers=auth())
    assert r.status_code == 200 and r.headers["Idempotent-Replayed"] == "true"
    assert r.content == first.content
    changed = payloads.epoch()
    changed["riders"] = []
    assert late.post(URL, json=changed, headers=auth()).json()["error"] == "epoch_conflict"


def test_demand_recorded_for_the_worker(make_client: MakeClient, any_store: Store) -> None:
    """Every epoch records its riders and how many instrumented and ordinary taxis it posted, under the
    city's local day; the one that opens the day's horizon also where each taxi stood. A replay records
    nothing again."""
    client = make_client(store=any_store)
    for epoch_id, minutes in (("before", -30.0), ("e1", 0.0), ("e2", 200 / 60), ("next-day", 24 * 60.0 + 1)):
        assert client.post(URL, json=payloads.epoch(epoch_id, minutes), headers=auth()).status_code == 200
    assert client.post(URL, json=payloads.epoch("e2", 200 / 60), headers=auth()).status_code == 200  # replay
    docs = [json.loads(d) for d in any_store.recorded_demand(CITY, "20261123")]
    assert [d["epoch_id"] for d in docs] == ["before", "e1", "e2"]
    assert [(r["id"], r["origin"], r["destination"]) for r in docs[1]["riders"]] == [
        ("r1", node_id(0, 0), node_id(4, 4)),
        ("r2", node_id(3, 3), node_id(1, 0)),
    ]
    assert all(d["fleet"] == {"instrumented": 2, "ordinary": 1} for d in docs)
    assert [("fleet_at_open" in d) for d in docs] == [False, True, False]  # 07:30 is before the horizon
    assert docs[1]["fleet_at_open"] == {
        "instrumented": [node_id(0, 1), node_id(4, 0)],
        "ordinary": [node_id(2, 2)],
    }
    (nxt,) = [json.loads(d) for d in any_store.recorded_demand(CITY, "20261124")]
    assert nxt["epoch_id"] == "next-day" and "fleet_at_open" in nxt  # the first epoch of that day's horizon
    assert any_store.recorded_epochs(CITY, ["20261123", "20261124", "20261125"]) == [3, 1, 0]


def test_unknown_exception_is_500_with_the_error_shape(make_client: MakeClient) -> None:
    store = MemoryStore()
    client = make_client(store=store, decide=FakeDecide(fail=RuntimeError("boom")), raise_errors=False)
    before = fingerprint(store)
    r = client.post(URL, json=payloads.epoch(), headers=auth())
    assert r.status_code == 500
    assert r.json() == {"error": "internal", "detail": r.json()["detail"], "fields": []}
    assert "RuntimeError" in r.json()["detail"]
    assert fingerprint(store) == before
    assert 'sd_epochs_total{outcome="error"} 1.0' in client.get("/metrics").text


@pytest.mark.parametrize("n_epochs", [3])
def test_sequence_of_epochs_on_redis(make_client: MakeClient, redis_store: Store, n_epochs: int) -> None:
    client = make_client(store=redis_store)
    for i in range(n_epochs):
        r = client.post(URL, json=payloads.epoch(f"e{i}", 20 * i), headers=auth())
        assert r.status_code == 200, r.text
    st = redis_store.load_state(CITY, [], [])
    assert (st.version, st.last_epoch_id) == (n_epochs, f"e{n_epochs - 1}")
    r = client.get(f"/v1/cities/{CITY}/coverage", headers=auth())
    assert r.status_code == 200 and r.json()["interval"] == "2026-11-23T08:00"


def test_commit_carries_retention(make_client: MakeClient) -> None:
    seen: list[EpochCommit] = []
    inner = MemoryStore()

    class Spy:
        def __getattr__(self, name: str) -> Any:
            return getattr(inner, name)

        def commit_epoch(self, city: str, commit: EpochCommit) -> CommitResult:
            seen.append(commit)
            return inner.commit_epoch(city, commit)

    client = make_client(store=Spy(), retention_s=7200)
    client.post(URL, json=payloads.epoch(), headers=auth())
    assert seen[0].retention_s == 7200
    assert dataclasses.asdict(seen[0])["expected_version"] == 0


def test_real_decide_end_to_end(make_client: MakeClient, any_store: Store) -> None:
    """The composition with ``services.dispatch.decide`` on the tiny lattice, on both stores."""
    from services.dispatch import decide

    client = make_client(store=any_store, decide=decide)
    assert client.post(f"/v1/cities/{CITY}/tasks", json=payloads.tasks(), headers=auth()).status_code == 200
    r = client.post(URL, json=payloads.epoch("e1", 0), headers=auth())
    assert r.status_code == 200, r.text
    body = r.json()
    by_rider = {m["rider_id"]: m for m in body["rider_matches"]}
    assert (
        by_rider["r1"]["taxi_id"] == "t0" and by_rider["r1"]["step"] == 1
    )  # the only instrumented vacant taxi
    assert by_rider["r2"]["taxi_id"] == "t1" and by_rider["r2"]["step"] == 2
    assert by_rider["r1"]["path"][0] == node_id(0, 1) and by_rider["r1"]["path"][-1] == node_id(4, 4)
    # Lambda in the store is exactly the G-route of t0's trip, in the epoch's interval
    cov = client.get(f"/v1/cities/{CITY}/coverage", headers=auth()).json()
    assert sorted(tuple(c["cell"]) for c in cov["cells"]) == sorted(map(tuple, by_rider["r1"]["cells"]))
    assert body["stats"]["gamma"] == pytest.approx(cov["gamma_so_far"])
    again = client.post(URL, json=payloads.epoch("e1", 0), headers=auth())
    assert again.headers["Idempotent-Replayed"] == "true" and again.content == r.content


def test_two_apps_on_one_redis_serialize(make_client: MakeClient, redis_url: str, redis_prefix: str) -> None:
    """Two API processes (two apps, two connections) posting different epochs at once: both commit."""
    import threading

    from app.adapters import RedisStore

    stores = [RedisStore(redis_url, prefix=redis_prefix) for _ in range(2)]
    clients = [make_client(store=s) for s in stores]
    results: dict[int, int] = {}

    def post(i: int) -> None:
        results[i] = clients[i].post(URL, json=payloads.epoch(f"e{i}", 5), headers=auth()).status_code

    threads = [threading.Thread(target=post, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == {0: 200, 1: 200}
    st = stores[0].load_state(CITY, [], [])
    assert st.version == 2
    for s in stores:
        s.close()


def test_tasks_left_pending_past_the_retention_expire(make_client: MakeClient, any_store: Store) -> None:
    """A task still pending when its scheduled time is older than the retention leaves the open set as
    ``expired`` (listed, never dispatched again); the epoch's decision never saw it."""
    fake = FakeDecide()
    client = make_client(store=any_store, decide=fake, retention_s=3600)
    assert client.post(f"/v1/cities/{CITY}/tasks", json=payloads.tasks(), headers=auth()).status_code == 200
    # poi-b (scheduled at +30 min) is still within an hour at +80 min; poi-a (-10 min) is not
    r = client.post(URL, json=payloads.epoch("e1", minutes=80.0, riders=[], taxis=[]), headers=auth())
    assert r.status_code == 200, r.text
    assert [[str(t.id) for t in call["tasks"]] for call in fake.calls] == [["poi-b"]]
    listed = client.get(f"/v1/cities/{CITY}/tasks", headers=auth()).json()["tasks"]
    status = {t["id"]: t["status"] for t in listed}
    assert status == {"poi-a": "expired", "poi-b": "pending"}
    assert [t.id for t in any_store.load_state(CITY, [], []).tasks] == ["poi-b"]


def test_epochs_beyond_the_solve_slots_wait_then_get_503_busy_and_change_nothing(
    make_client: MakeClient,
) -> None:
    import threading

    inner, entered, gate = FakeDecide(), threading.Event(), threading.Event()

    def held(*args: Any) -> Any:
        if not entered.is_set():  # the first epoch holds the only slot until the gate opens
            entered.set()
            assert gate.wait(timeout=30.0)
        return inner(*args)

    store = MemoryStore()
    client = make_client(store=store, decide=held, max_solves=1, solve_queue_s=0.2)
    first: list[Any] = []
    thread = threading.Thread(
        target=lambda: first.append(
            client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch("e1"), headers=auth())
        )
    )
    thread.start()
    assert entered.wait(timeout=30.0)
    before = fingerprint(store)
    r = client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch("e2", 1.0), headers=auth())
    assert r.status_code == 503, r.text
    assert r.json()["error"] == "busy" and "solve slot" in r.json()["detail"]
    assert fingerprint(store) == before  # refused before anything was read or written
    gate.set()
    thread.join(timeout=30.0)
    assert first[0].status_code == 200, first[0].text
    again = client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch("e2", 1.0), headers=auth())
    assert again.status_code == 200 and again.headers.get("Idempotent-Replayed") is None
    assert len(inner.calls) == 2  # e1 and e2 once each: the refused post solved nothing


def test_the_whole_epoch_request_holds_the_foreground(
    make_client: MakeClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The embedded worker's runs stay stopped while the API parses an epoch, not only while it solves: the
    foreground is held when the body is parsed and when the decision is made, and released after, also
    when the body is refused."""
    import contextlib

    from app.api.bodies import epoch_post

    client = make_client()
    held: list[int] = []
    depth = [0]

    @contextlib.contextmanager
    def foreground() -> Any:
        depth[0] += 1
        try:
            yield
        finally:
            depth[0] -= 1

    client.app.state.use_cases.epochs.foreground = foreground  # type: ignore[attr-defined]

    def parse_seen(*args: Any) -> Any:
        held.append(depth[0])
        return epoch_post(*args)

    monkeypatch.setattr("app.api.writes.epoch_post", parse_seen)
    r = client.post(URL, json=payloads.epoch(), headers=auth())
    assert r.status_code == 200, r.text
    assert held == [1] and depth[0] == 0
    r = client.post(URL, content=b"{not json", headers={**auth(), "Content-Type": "application/json"})
    assert r.status_code in (400, 422), r.text
    assert held == [1, 1] and depth[0] == 0


def test_each_write_resolves_its_city_once(make_client: MakeClient, monkeypatch: pytest.MonkeyPatch) -> None:
    """A task registration and an epoch post, committed or replayed, look their city up once: the node
    indices of the request and its use case read the same City; so does a stored epoch's routes."""
    from app.adapters.city_registry import CityRegistry

    client = make_client()
    looked_up: list[str] = []
    get = CityRegistry.get

    def counted(self: CityRegistry, name: str) -> Any:
        looked_up.append(name)
        return get(self, name)

    monkeypatch.setattr(CityRegistry, "get", counted)
    assert client.post(f"/v1/cities/{CITY}/tasks", json=payloads.tasks(), headers=auth()).status_code == 200
    assert looked_up == [CITY]
    for replay in (False, True):
        looked_up.clear()
        r = client.post(URL, json=payloads.epoch(), headers=auth())
        assert r.status_code == 200 and ("Idempotent-Replayed" in r.headers) is replay, r.text
        assert looked_up == [CITY]
    looked_up.clear()
    r = client.get(f"/v1/cities/{CITY}/epochs/{payloads.epoch()['epoch_id']}/routes.geojson", headers=auth())
    assert r.status_code == 200, r.text
    assert looked_up == [CITY]
