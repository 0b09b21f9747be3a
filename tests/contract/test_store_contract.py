"""The ``Store`` contract, run against ``MemoryStore`` and ``RedisStore`` alike."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.adapters import RedisStore
from app.ports import CityState, EpochCommit, Store, StoredEpoch, StoreUnavailable, local_day
from services.ledger import Ledger, apply_decision
from services.model import IntervalKey, Task, TaskId, TaxiId, Visit

from .conftest import StoreCase

CITY = "testville"
K1, K2, K3 = IntervalKey(480), IntervalKey(481), IntervalKey(7)
A, B, C = TaxiId("taxi-a"), TaxiId("taxi-b"), TaxiId("taxi-c")
T0 = 1_700_000_000.25  # 2023-11-14 22:13:20.25 UTC


def visit(taxi: str, k: int, cell: int) -> Visit:
    return Visit(TaxiId(taxi), IntervalKey(k), cell)


def commit(
    epoch_id: str,
    *,
    version: int,
    time_s: float = T0,
    visits: Sequence[Visit] = (),
    tasks: Sequence[Task] = (),
    body_hash: str | None = None,
    demand_json: str | None = None,
    retention_s: int = 8 * 86400,
    demand_day: str | None = None,
) -> EpochCommit:
    return EpochCommit(
        epoch_id=epoch_id,
        body_hash=body_hash or f"hash-of-{epoch_id}",
        time_s=time_s,
        expected_version=version,
        visits=list(visits),
        task_updates=list(tasks),
        response_json=f'{{"epoch_id": "{epoch_id}"}}',
        retention_s=retention_s,
        demand_json=demand_json,
        demand_day=(demand_day or local_day(time_s, "UTC")) if demand_json is not None else "",
    )


def full_state(store: Store, city: str = CITY) -> tuple[object, ...]:
    """Everything the port can tell about a city's intervals K1..K3 and taxis A..C."""
    ks = [K1, K2, K3]
    return (
        store.load_state(city, ks, [A, B, C]),
        store.list_intervals(city),
        store.list_tasks(city),
        [store.interval_counts(city, k) for k in ks],
        store.recorded_demand(city, local_day(T0, "UTC")),
    )


def task(tid: str, node: int = 3, at: float = T0, **kw: object) -> Task:
    return Task(TaskId(tid), node, at, **kw)  # type: ignore[arg-type]


# -- state and counting ---------------------------------------------------------------------------------


def test_empty_state(store: Store) -> None:
    state = store.load_state(CITY, [K1, K2], [A])
    assert state == CityState(
        version=0,
        last_epoch_id=None,
        last_epoch_time_s=None,
        counts={K1: {}, K2: {}},
        visited={A: set()},
        tasks=[],
    )
    assert store.list_intervals(CITY) == []
    assert store.list_tasks(CITY) == []
    assert store.interval_counts(CITY, K1) == {}
    assert store.get_epoch(CITY, "e1") is None
    assert store.recorded_demand(CITY, "20231114") == []
    store.ping()


def test_commit_then_load_reflects_counts(store: Store) -> None:
    result = store.commit_epoch(
        CITY, commit("e1", version=0, visits=[visit(A, K1, 5), visit(A, K1, 6), visit(A, K2, 5)])
    )
    assert result.status == "committed"
    assert result.new_version == 1
    state = store.load_state(CITY, [K1, K2, K3], [A, B])
    assert state.version == 1
    assert state.last_epoch_id == "e1"
    assert state.last_epoch_time_s == T0
    assert state.counts == {K1: {5: 1, 6: 1}, K2: {5: 1}, K3: {}}
    assert state.visited == {A: {(K1, 5), (K1, 6), (K2, 5)}, B: set()}
    assert store.interval_counts(CITY, K1) == {5: 1, 6: 1}
    assert store.get_epoch(CITY, "e1") == StoredEpoch("e1", "hash-of-e1", T0, '{"epoch_id": "e1"}')


def test_load_state_only_returns_what_was_asked(store: Store) -> None:
    store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 5), visit(B, K2, 6)]))
    state = store.load_state(CITY, [K2], [A])
    assert state.counts == {K2: {6: 1}}
    assert state.visited == {A: set()}
    state = store.load_state(CITY, [K1, K1], [B, B])  # repeats are harmless
    assert state.counts == {K1: {5: 1}}
    assert state.visited == {B: set()}


def test_load_state_reads_visits_from_an_interval_on(store: Store) -> None:
    store.commit_epoch(
        CITY,
        commit("e1", version=0, visits=[visit(A, K1, 5), visit(A, K2, 6), visit(A, K3, 7), visit(B, K1, 5)]),
    )
    state = store.load_state(CITY, [K1, K2, K3], [A, B], visits_from=K2)
    assert state.counts == {K1: {5: 2}, K2: {6: 1}, K3: {7: 1}}  # every interval's counts
    assert state.visited == {A: {(K2, 6)}, B: set()}  # the pairs from K2 on (K3 is an earlier interval)


def test_a_loaded_state_stays_as_it_was_read(store: Store) -> None:
    """A state read before a commit keeps the counts and the pairs it was read with (a store may hand out
    its own frozen sets, never one that a later commit grows)."""
    store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 5), visit(B, K1, 5)]))
    before = store.load_state(CITY, [K1, K2], [A, B])
    again = store.load_state(CITY, [K1, K2], [A, B])
    visits = [visit(A, K1, 6), visit(A, K2, 7), visit(B, K1, 6)]
    assert store.commit_epoch(CITY, commit("e2", version=1, visits=visits)).status == "committed"
    for state in (before, again):
        assert state.counts == {K1: {5: 2}, K2: {}}
        assert state.visited == {A: {(K1, 5)}, B: {(K1, 5)}}
    after = store.load_state(CITY, [K1, K2], [A, B])
    assert after.visited == {A: {(K1, 5), (K1, 6), (K2, 7)}, B: {(K1, 5), (K1, 6)}}


def test_same_visit_in_two_epochs_counts_once(store: Store) -> None:
    store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 5)]))
    result = store.commit_epoch(CITY, commit("e2", version=1, visits=[visit(A, K1, 5), visit(A, K1, 5)]))
    assert result.status == "committed"
    assert store.interval_counts(CITY, K1) == {5: 1}
    assert store.load_state(CITY, [K1], [A]).visited == {A: {(K1, 5)}}


def test_two_taxis_in_one_cell_count_two(store: Store) -> None:
    store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 5), visit(B, K1, 5)]))
    store.commit_epoch(CITY, commit("e2", version=1, visits=[visit(C, K1, 5), visit(A, K2, 5)]))
    assert store.interval_counts(CITY, K1) == {5: 3}
    assert store.interval_counts(CITY, K2) == {5: 1}


def test_cities_are_independent(store: Store) -> None:
    store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 5)]))
    assert store.load_state("elsewhere", [K1], [A]).version == 0
    assert store.interval_counts("elsewhere", K1) == {}
    assert store.get_epoch("elsewhere", "e1") is None
    assert store.commit_epoch("elsewhere", commit("e1", version=0)).status == "committed"


def test_ids_and_times_round_trip_exactly(store: Store) -> None:
    taxi, epoch_id, t = TaxiId("出租车 7:{x}"), "epoch:ü/1", 1_700_000_000.123456789
    store.commit_epoch(CITY, commit(epoch_id, version=0, time_s=t, visits=[visit(taxi, K1, 0)]))
    state = store.load_state(CITY, [K1], [taxi])
    assert state.last_epoch_id == epoch_id
    assert state.last_epoch_time_s == t
    assert state.visited == {taxi: {(K1, 0)}}
    stored = store.get_epoch(CITY, epoch_id)
    assert stored is not None and stored.time_s == t


# -- the checks of commit_epoch, in order ---------------------------------------------------------------


def test_duplicate_epoch_returns_stored_record_and_changes_nothing(case: StoreCase) -> None:
    store = case.store
    day = local_day(T0, "UTC")
    first = commit("e1", version=0, visits=[visit(A, K1, 5)], tasks=[task("p1")], demand_json='["r1"]')
    store.commit_epoch(CITY, first)
    before, raw_before = full_state(store), case.raw()
    # same id, different everything: version, time, visits, tasks, hash, demand
    again = commit(
        "e1",
        version=1,
        time_s=T0 + 60,
        visits=[visit(B, K1, 5), visit(A, K2, 9)],
        tasks=[task("p2")],
        body_hash="other",
        demand_json='["r2"]',
    )
    result = store.commit_epoch(CITY, again)
    assert result.status == "duplicate"
    assert result.stored == StoredEpoch("e1", "hash-of-e1", T0, '{"epoch_id": "e1"}')
    assert result.new_version is None
    assert full_state(store) == before
    assert case.raw() == raw_before
    assert store.recorded_demand(CITY, day) == ['["r1"]']
    # a stale version does not hide a duplicate either: the id check comes first
    assert store.commit_epoch(CITY, commit("e1", version=0)).status == "duplicate"


def test_version_mismatch_changes_nothing(case: StoreCase) -> None:
    store = case.store
    store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 5)]))
    before, raw_before = full_state(store), case.raw()
    for wrong in (0, 2, 7):
        late = commit(f"e-{wrong}", version=wrong, time_s=T0 + 1, visits=[visit(B, K1, 5)], tasks=[task("p")])
        result = store.commit_epoch(CITY, late)
        assert result.status == "version_mismatch"
        assert result.stored is None and result.new_version is None
    assert full_state(store) == before
    assert case.raw() == raw_before
    assert store.get_epoch(CITY, "e-0") is None


def test_stale_time_changes_nothing(case: StoreCase) -> None:
    store = case.store
    store.commit_epoch(CITY, commit("e1", version=0, time_s=T0, visits=[visit(A, K1, 5)]))
    before, raw_before = full_state(store), case.raw()
    old = commit("e0", version=1, time_s=T0 - 0.001, visits=[visit(B, K1, 5)], demand_json="[]")
    result = store.commit_epoch(CITY, old)
    assert result.status == "stale"
    assert full_state(store) == before
    assert case.raw() == raw_before
    # the version check comes before the time check
    assert store.commit_epoch(CITY, commit("e0", version=0, time_s=T0 - 1)).status == "version_mismatch"


def test_equal_time_is_allowed(store: Store) -> None:
    assert store.commit_epoch(CITY, commit("e1", version=0, time_s=T0)).status == "committed"
    result = store.commit_epoch(CITY, commit("e2", version=1, time_s=T0, visits=[visit(A, K1, 1)]))
    assert result.status == "committed"
    assert result.new_version == 2
    state = store.load_state(CITY, [K1], [])
    assert (state.version, state.last_epoch_id, state.last_epoch_time_s) == (2, "e2", T0)


def test_empty_commit_bumps_version(store: Store) -> None:
    for v in range(3):
        assert store.commit_epoch(CITY, commit(f"e{v}", version=v, time_s=T0 + v)).new_version == v + 1
    assert store.load_state(CITY, [], []).version == 3
    assert store.list_intervals(CITY) == []


# -- tasks ---------------------------------------------------------------------------------------------


def test_put_tasks_created_then_unchanged(store: Store) -> None:
    p1, p2 = task("p1", location=(116.4, 39.9)), task("p2", node=4)
    result = store.put_tasks(CITY, [p1, p2])
    assert (result.created, result.unchanged, result.conflicts) == (["p1", "p2"], [], [])
    result = store.put_tasks(CITY, [p2, p1, task("p3")])
    assert (result.created, result.unchanged, result.conflicts) == (["p3"], ["p2", "p1"], [])
    assert store.list_tasks(CITY) == [p1, p2, task("p3")]
    assert store.put_tasks(CITY, []).created == []


def test_put_tasks_same_registration_after_assignment_is_unchanged(store: Store) -> None:
    p1 = task("p1", location=(116.4, 39.9))
    store.put_tasks(CITY, [p1])
    assigned = task(
        "p1", location=(116.4, 39.9), status="assigned", completed_at_s=T0 + 300, taxi_id=A, mode="active"
    )
    store.commit_epoch(CITY, commit("e1", version=0, tasks=[assigned]))
    result = store.put_tasks(CITY, [p1])
    assert (result.created, result.unchanged, result.conflicts) == ([], ["p1"], [])
    assert store.list_tasks(CITY) == [assigned]  # the lifecycle is not reset


@pytest.mark.parametrize(
    ("original", "changed"),
    [
        (task("p1"), task("p1", node=4)),
        (task("p1"), task("p1", at=T0 + 1)),
        (task("p1"), task("p1", location=(116.4, 39.9))),
        (task("p1", location=(116.4, 39.9)), task("p1")),
        (task("p1", location=(116.4, 39.9)), task("p1", location=(116.4, 39.90001))),
    ],
    ids=["node", "time", "location-added", "location-dropped", "location-moved"],
)
def test_put_tasks_conflict_writes_nothing(case: StoreCase, original: Task, changed: Task) -> None:
    store = case.store
    store.put_tasks(CITY, [original])
    raw_before = case.raw()
    result = store.put_tasks(CITY, [task("new"), changed, task("p1b")])
    assert result.conflicts == ["p1"]
    assert result.created == []
    assert store.list_tasks(CITY) == [original]
    assert case.raw() == raw_before


def test_put_tasks_repeated_id_in_one_request(store: Store) -> None:
    result = store.put_tasks(CITY, [task("p1"), task("p1")])
    assert (result.created, result.unchanged, result.conflicts) == (["p1"], [], [])
    result = store.put_tasks(CITY, [task("p2"), task("p2", node=9)])
    assert result.conflicts == ["p2"]
    assert [t.id for t in store.list_tasks(CITY)] == ["p1"]


def test_task_updates_in_commits(store: Store) -> None:
    store.put_tasks(CITY, [task("p1"), task("p2")])
    assigned = task("p1", status="assigned", completed_at_s=T0 + 100, taxi_id=A, mode="active")
    done = task("p1", status="completed", completed_at_s=T0 + 100, taxi_id=A, mode="active")
    store.commit_epoch(CITY, commit("e1", version=0, tasks=[assigned]))
    assert store.load_state(CITY, [], []).tasks == [assigned, task("p2")]
    store.commit_epoch(CITY, commit("e2", version=1, time_s=T0 + 200, tasks=[done, task("p3", node=1)]))
    assert store.list_tasks(CITY) == [done, task("p2"), task("p3", node=1)]
    # a completed task has left what an epoch reads, and is still listed
    assert store.load_state(CITY, [], []).tasks == [task("p2"), task("p3", node=1)]
    # a rejected commit does not touch tasks
    store.commit_epoch(CITY, commit("e3", version=0, time_s=T0 + 300, tasks=[task("p2", status="completed")]))
    assert store.list_tasks(CITY) == [done, task("p2"), task("p3", node=1)]


def test_finished_tasks_are_history_kept_for_the_retention(store: Store) -> None:
    """Completed and expired tasks leave the open set; they stay listed (and their ids registered, so a
    repeated registration is unchanged, another one a conflict) until an epoch commits more than the
    retention after they finished."""
    store.put_tasks(CITY, [task("p1"), task("p2"), task("p3")])
    done = task("p1", status="completed", completed_at_s=T0, taxi_id=A, mode="passive")
    gone = task("p2", status="expired")
    store.commit_epoch(CITY, commit("e1", version=0, time_s=T0, tasks=[done, gone], retention_s=3600))
    assert store.load_state(CITY, [], []).tasks == [task("p3")]
    assert store.list_tasks(CITY) == [done, gone, task("p3")]
    again = store.put_tasks(CITY, [task("p1"), task("p2", node=9)])
    assert again.unchanged == [] and again.conflicts == [TaskId("p2")]
    assert store.put_tasks(CITY, [task("p1")]).unchanged == [TaskId("p1")]
    store.commit_epoch(CITY, commit("e2", version=1, time_s=T0 + 3600, retention_s=3600))
    assert store.list_tasks(CITY) == [done, gone, task("p3")]  # finished exactly one retention ago: kept
    store.commit_epoch(CITY, commit("e3", version=2, time_s=T0 + 3601, retention_s=3600))
    assert store.list_tasks(CITY) == [task("p3")]
    assert store.put_tasks(CITY, [task("p1")]).created == [TaskId("p1")]  # forgotten: a new task


def test_finished_tasks_leave_one_retention_after_each_finished(store: Store) -> None:
    """Tasks finished at different epochs leave at different epochs: each one retention after its own."""
    store.put_tasks(CITY, [task("p1"), task("p2"), task("p3")])
    first = task("p1", status="expired")
    store.commit_epoch(CITY, commit("e1", version=0, time_s=T0, tasks=[first], retention_s=3600))
    second = task("p2", status="completed", completed_at_s=T0 + 1800, taxi_id=A, mode="passive")
    store.commit_epoch(CITY, commit("e2", version=1, time_s=T0 + 1800, tasks=[second], retention_s=3600))
    store.commit_epoch(CITY, commit("e3", version=2, time_s=T0 + 3601, retention_s=3600))
    assert store.list_tasks(CITY) == [second, task("p3")]  # only the first is past its retention
    store.commit_epoch(CITY, commit("e4", version=3, time_s=T0 + 5401, retention_s=3600))
    assert store.list_tasks(CITY) == [task("p3")]


# -- intervals and demand ------------------------------------------------------------------------------


def test_list_intervals_ascending(store: Store) -> None:
    store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K2, 1), visit(A, K3, 1)]))
    store.commit_epoch(CITY, commit("e2", version=1, visits=[visit(B, K1, 1), visit(B, K2, 2)]))
    assert store.list_intervals(CITY) == [K3, K1, K2]  # 7 < 480 < 481: numeric, not lexicographic


def test_recorded_demand_by_the_day_each_commit_names(store: Store) -> None:
    """The store keeps each commit's demand under the day the commit names (the city's local day, which
    the epoch use case computes), in commit order, and counts a day's records without reading them."""
    midnight = 1_700_006_400.0 - 8 * 3600  # 2023-11-15 00:00:00 in Shanghai (16:00 UTC the day before)
    tz = "Asia/Shanghai"
    for version, (epoch, t, doc) in enumerate(
        [
            ("e1", midnight - 1, '["a"]'),
            ("e2", midnight, '["b"]'),
            ("e3", midnight + 1, None),
            ("e4", midnight + 5, '["c"]'),
        ]
    ):
        day = local_day(t, tz) if doc is not None else None
        assert (
            store.commit_epoch(
                CITY, commit(epoch, version=version, time_s=t, demand_json=doc, demand_day=day)
            ).status
            == "committed"
        )
    assert store.recorded_demand(CITY, "20231114") == ['["a"]']  # 23:59:59 in Shanghai, 15:59:59 UTC
    assert store.recorded_demand(CITY, "20231115") == ['["b"]', '["c"]']
    assert store.recorded_demand(CITY, "20231116") == []
    assert store.recorded_epochs(CITY, ["20231116", "20231115", "20231114"]) == [0, 2, 1]
    assert store.recorded_epochs(CITY, []) == []
    with pytest.raises(ValueError, match="demand_day"):
        EpochCommit("e5", "h", midnight, 4, (), (), "{}", demand_json='["d"]')


# -- property: Lambda is the number of distinct taxis per (interval, cell) -----------------------------

_visits = st.lists(
    st.tuples(st.sampled_from(["a", "b", "c", "d"]), st.integers(0, 2), st.integers(0, 4)), max_size=30
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(epochs=st.lists(_visits, min_size=1, max_size=5), replays=st.lists(st.integers(0, 4), max_size=3))
def test_counts_equal_distinct_taxis_per_cell(
    make_case: Callable[[], StoreCase], epochs: list[list[tuple[str, int, int]]], replays: list[int]
) -> None:
    store = make_case().store
    for i, batch in enumerate(epochs):
        result = store.commit_epoch(
            CITY, commit(f"e{i}", version=i, time_s=T0 + i, visits=[visit(*v) for v in batch])
        )
        assert result.status == "committed"
    for i in replays:  # retries of committed epochs change nothing
        if i < len(epochs):
            assert store.commit_epoch(CITY, commit(f"e{i}", version=0)).status == "duplicate"
    taxis_at: dict[tuple[int, int], set[str]] = {}
    for batch in epochs:
        for taxi, k, cell in batch:
            taxis_at.setdefault((k, cell), set()).add(taxi)
    for k in range(3):
        expected = {cell: len(ts) for (kk, cell), ts in taxis_at.items() if kk == k}
        assert store.interval_counts(CITY, IntervalKey(k)) == expected
    assert store.list_intervals(CITY) == sorted({k for k, _ in taxis_at})
    state = store.load_state(CITY, [IntervalKey(k) for k in range(3)], [TaxiId(t) for t in "abcde"])
    assert state.version == len(epochs)
    for t in "abcde":
        assert state.visited[TaxiId(t)] == {(k, cell) for (k, cell), ts in taxis_at.items() if t in ts}


# -- Redis specifics -----------------------------------------------------------------------------------


def test_retention_ttl_on_redis_keys(redis_store: RedisStore, redis_url: str) -> None:
    import redis

    retention = 3600
    redis_store.commit_epoch(
        CITY, commit("e1", version=0, visits=[visit(A, K1, 5)], demand_json="[]", retention_s=retention)
    )
    redis_store.put_tasks(CITY, [task("p1")])
    p = f"{redis_store.prefix}:{{{CITY}}}"
    client = redis.Redis.from_url(url=redis_url, decode_responses=True)
    try:
        # the meta too: an epoch dated far ahead cannot block the city beyond the retention
        for key in (
            f"{p}:count:{K1}",
            f"{p}:visit:{K1}:{A}",
            f"{p}:epoch:e1",
            f"{p}:demand:{local_day(T0, 'UTC')}",
            f"{p}:meta",
        ):
            assert 0 < client.ttl(key) <= retention, key
        for key in (f"{p}:tasks", f"{p}:tasks:rev", f"{p}:intervals"):
            assert client.ttl(key) == -1, key  # exists, no expiry
        meta = client.hgetall(f"{p}:meta")
        assert len(meta.pop("rev")) == 32  # the state revision (app/adapters/redis_mirror.py)
        assert meta == {"version": "1", "last_time": repr(T0), "last_epoch": "e1"}
    finally:
        client.close()


def test_redis_intervals_whose_counts_expired_are_not_listed(redis_store: RedisStore, redis_url: str) -> None:
    import redis

    redis_store.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 5), visit(A, K2, 5)]))
    client = redis.Redis.from_url(url=redis_url)
    try:
        client.delete(f"{redis_store.prefix}:{{{CITY}}}:count:{K1}")  # as if expired
    finally:
        client.close()
    assert redis_store.list_intervals(CITY) == [K2]


def _closed_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize(
    "call",
    [
        lambda s: s.ping(),
        lambda s: s.load_state(CITY, [K1], [A]),
        lambda s: s.commit_epoch(CITY, commit("e1", version=0, visits=[visit(A, K1, 1)])),
        lambda s: s.put_tasks(CITY, [task("p1")]),
        lambda s: s.get_epoch(CITY, "e1"),
        lambda s: s.list_tasks(CITY),
        lambda s: s.interval_counts(CITY, K1),
        lambda s: s.list_intervals(CITY),
        lambda s: s.recorded_demand(CITY, "20231114"),
    ],
    ids=[
        "ping",
        "load_state",
        "commit_epoch",
        "put_tasks",
        "get_epoch",
        "list_tasks",
        "interval_counts",
        "list_intervals",
        "recorded_demand",
    ],
)
def test_redis_down_raises_store_unavailable(call: Callable[[Store], object]) -> None:
    port = _closed_port()
    store = RedisStore(f"redis://:secret@127.0.0.1:{port}/0", socket_timeout_s=0.5)
    started = time.monotonic()
    with pytest.raises(StoreUnavailable, match=f"127.0.0.1:{port}") as info:
        call(store)
    assert "secret" not in str(info.value)
    assert time.monotonic() - started < 3.0  # fails fast, no long retry backoff
    store.close()


def test_redis_that_never_answers_raises_store_unavailable() -> None:
    import socket

    with socket.socket() as silent:  # accepts connections (backlog) but never replies
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        port = silent.getsockname()[1]
        store = RedisStore(f"redis://127.0.0.1:{port}/0", socket_timeout_s=0.3)
        started = time.monotonic()
        with pytest.raises(StoreUnavailable, match="unreachable"):
            store.ping()
        assert time.monotonic() - started < 3.0
        store.close()


# -- property: every store commits exactly what the core's apply_decision does ---------------------------

_updates = st.lists(
    st.tuples(st.sampled_from(["p1", "p2", "p3"]), st.sampled_from(["assigned", "completed"])), max_size=3
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(epochs=st.lists(st.tuples(_visits, _updates), min_size=1, max_size=5))
def test_commit_is_apply_decision(
    make_case: Callable[[], StoreCase], epochs: list[tuple[list[tuple[str, int, int]], list[tuple[str, str]]]]
) -> None:
    """The Redis commit script (and the memory store) against ``services.ledger.apply_decision``."""
    store = make_case().store
    ledger = Ledger()
    store.put_tasks(CITY, [task(t) for t in ("p1", "p2", "p3")])
    apply_decision(ledger, (), [task(t) for t in ("p1", "p2", "p3")])
    for i, (batch, updates) in enumerate(epochs):
        visits = [visit(*v) for v in batch]
        done = [task(t, status=status, taxi_id=TaxiId("a"), completed_at_s=T0 + i) for t, status in updates]
        before = {k: dict(row) for k, row in ledger.counts.items()}
        counted = apply_decision(ledger, visits, done)
        result = store.commit_epoch(
            CITY, commit(f"e{i}", version=i, time_s=T0 + i, visits=visits, tasks=done)
        )
        assert result.status == "committed"
        for v in counted:  # each counted visit raised its cell by one, nothing else changed
            before.setdefault(v.interval, {}).setdefault(v.cell, 0)
            before[v.interval][v.cell] += 1
        assert {k: row for k, row in before.items() if row} == {
            k: row for k, row in ledger.counts.items() if row
        }
        for k in range(3):
            assert store.interval_counts(CITY, IntervalKey(k)) == ledger.counts.get(IntervalKey(k), {})
    intervals = [IntervalKey(k) for k in range(3)]
    state = store.load_state(CITY, intervals, [TaxiId(t) for t in "abcd"])
    for taxi, pairs in state.visited.items():
        assert pairs == {(k, c) for (k, t), cells in ledger.visits.items() if t == taxi for c in cells}
    listed = {**ledger.done, **ledger.tasks}  # open records over finished ones of the same id
    assert sorted(store.list_tasks(CITY), key=lambda t: t.id) == sorted(listed.values(), key=lambda t: t.id)
    # an epoch reads the open tasks only: a completed task has left the set
    assert sorted(state.tasks, key=lambda t: t.id) == sorted(ledger.tasks.values(), key=lambda t: t.id)


# -- a re-sent commit, rewinding and resetting the epoch stream ----------------------------------------------


def test_commit_sent_again_with_its_nonce_is_committed_once(case: StoreCase) -> None:
    store = case.store
    first = dataclasses.replace(commit("e1", version=0, visits=[visit(A, K1, 5)]), nonce="n-1")
    assert store.commit_epoch(CITY, first).status == "committed"
    after = case.raw()
    # the same attempt arriving again (its reply was lost): committed, and nothing applied twice
    again = store.commit_epoch(CITY, first)
    assert again.status == "committed"
    assert case.raw() == after
    # another attempt with the same id (another process, a client retry): a duplicate, as ever
    other = dataclasses.replace(first, nonce="n-2")
    dup = store.commit_epoch(CITY, other)
    assert dup.status == "duplicate" and dup.stored is not None and dup.stored.body_hash == first.body_hash
    no_nonce = dataclasses.replace(first, nonce="")
    assert store.commit_epoch(CITY, no_nonce).status == "duplicate"
    assert store.load_state(CITY, [K1], [A]).version == 1
    assert case.raw() == after


def test_rewind_sets_the_last_time_back_and_keeps_the_rest(case: StoreCase) -> None:
    store = case.store
    assert store.rewind_epochs(CITY, T0).status == "empty"
    store.commit_epoch(CITY, commit("e1", version=0, time_s=T0, visits=[visit(A, K1, 5)]))
    store.commit_epoch(CITY, commit("e2", version=1, time_s=T0 + 1e9))  # the typo: 31 years ahead
    assert store.commit_epoch(CITY, commit("e3", version=2, time_s=T0 + 60)).status == "stale"
    before = full_state(store)
    ahead = store.rewind_epochs(CITY, T0 + 2e9)
    assert (ahead.status, ahead.previous_time_s, ahead.version) == ("ahead", T0 + 1e9, 2)
    assert full_state(store) == before
    done = store.rewind_epochs(CITY, T0 + 30)
    assert (done.status, done.previous_time_s, done.version) == ("rewound", T0 + 1e9, 2)
    state = store.load_state(CITY, [K1], [A])
    assert (state.version, state.last_epoch_id, state.last_epoch_time_s) == (2, "e2", T0 + 30)
    assert state.counts == {K1: {5: 1}}
    assert store.commit_epoch(CITY, commit("e0", version=2, time_s=T0 + 29)).status == "stale"
    assert store.commit_epoch(CITY, commit("e3", version=2, time_s=T0 + 60)).status == "committed"


def test_reset_forgets_the_stream_but_not_the_fleet(case: StoreCase) -> None:
    from app.ports import FleetRecord

    store = case.store
    assert store.reset_epochs(CITY) == 0
    store.put_tasks(CITY, [task("p1"), task("p2")])
    store.commit_epoch(
        CITY,
        commit("e1", version=0, visits=[visit(A, K1, 5)], tasks=[task("p1", status="completed")],
               demand_json="{}"),
    )  # fmt: skip
    store.commit_epoch("other", commit("e1", version=0, visits=[visit(A, K1, 5)]))
    record = FleetRecord("published", T0, 1, version=1, body_json="{}")
    assert store.publish_recommendation(CITY, record, 10).status == "published"
    lock = store.acquire_lock(CITY, "solve", 60)
    assert store.reset_epochs(CITY) > 0
    state = store.load_state(CITY, [K1], [A])
    assert (state.version, state.last_epoch_id, state.counts, state.tasks) == (0, None, {K1: {}}, [])
    assert store.get_epoch(CITY, "e1") is None and store.list_tasks(CITY) == []
    assert store.list_intervals(CITY) == [] and store.recorded_demand(CITY, local_day(T0, "UTC")) == []
    # the fleet records, the lock and the other city stay
    assert store.current_recommendation(CITY) == record
    assert lock is not None and store.acquire_lock(CITY, "solve", 60) is None
    assert store.load_state("other", [K1], [A]).counts == {K1: {5: 1}}
    # the stream starts again, with an id used before
    assert store.commit_epoch(CITY, commit("e1", version=0)).status == "committed"


def test_redis_replies_are_parsed_by_hiredis() -> None:
    """The C parser is installed and picked up (``redis[hiredis]``): an epoch of 600 instrumented taxis
    reads ~2,400 visit sets, and redis-py's Python parser took 73 ms of a Manhattan epoch's state load (34
    with hiredis)."""
    import redis.connection

    assert redis.connection.DefaultParser.__name__ == "_HiredisParser"
