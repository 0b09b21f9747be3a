"""``MemoryStore`` retention: counts, visits, epoch records and demand expire like their Redis keys."""

from __future__ import annotations

from app.adapters import MemoryStore
from app.ports import EpochCommit
from services.model import IntervalKey, Task, TaskId, TaxiId, Visit

CITY = "testville"
T0 = 1_700_000_000.0
A, B = TaxiId("a"), TaxiId("b")
K1, K2 = IntervalKey(1), IntervalKey(2)


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _commit(epoch_id: str, version: int, visits: list[Visit], retention_s: int) -> EpochCommit:
    return EpochCommit(
        epoch_id=epoch_id,
        body_hash="h",
        time_s=T0 + version,
        expected_version=version,
        visits=visits,
        task_updates=[Task(TaskId(f"t-{epoch_id}"), 1, T0)],
        response_json="{}",
        retention_s=retention_s,
        demand_json="[]",
        demand_day="20231114",
    )


def test_entries_expire_after_retention_and_are_refreshed_when_touched() -> None:
    clock = FakeClock()
    store = MemoryStore(clock=clock)
    store.commit_epoch(CITY, _commit("e1", 0, [Visit(A, K1, 5), Visit(A, K2, 5)], retention_s=100))
    clock.now += 60
    store.commit_epoch(CITY, _commit("e2", 1, [Visit(B, K2, 5)], retention_s=100))  # refreshes K2's count
    clock.now += 50  # e1 and K1 (and A's visits) are 110 s old; e2 and K2's count 50 s
    assert store.get_epoch(CITY, "e1") is None
    assert store.get_epoch(CITY, "e2") is not None
    assert store.interval_counts(CITY, K1) == {}
    assert store.interval_counts(CITY, K2) == {5: 2}
    assert store.list_intervals(CITY) == [K2]
    state = store.load_state(CITY, [K1, K2], [A, B])
    assert state.visited == {A: set(), B: {(K2, 5)}}
    assert state.version == 2  # the meta lives for the retention after the last commit; tasks never expire
    assert [t.id for t in state.tasks] == ["t-e1", "t-e2"]
    assert store.recorded_demand(CITY, "20231114") == ["[]", "[]"]
    clock.now += 100
    assert store.list_intervals(CITY) == []
    assert store.recorded_demand(CITY, "20231114") == []
    # the meta expired with the rest: the stream starts again (an epoch dated far ahead cannot block the
    # city beyond the retention either); tasks stay
    state = store.load_state(CITY, [], [])
    assert (state.version, state.last_epoch_id, state.last_epoch_time_s) == (0, None, None)
    assert [t.id for t in state.tasks] == ["t-e1", "t-e2"]
    # an expired epoch id may be committed again (Redis behaves the same once the record's key expires)
    assert store.commit_epoch(CITY, _commit("e1", 0, [], retention_s=100)).status == "committed"


def test_loaded_visits_follow_every_commit_and_expiry() -> None:
    """load_state keeps the (interval, cell) pairs it built for a taxi: they must follow the ledger when a
    later commit adds cells, when the visits expire, and when they come back after expiring."""
    clock = FakeClock()
    store = MemoryStore(clock=clock)
    store.commit_epoch(CITY, _commit("e1", 0, [Visit(A, K1, 5)], retention_s=100))
    assert store.load_state(CITY, [K1, K2], [A, B]).visited == {A: {(K1, 5)}, B: set()}
    store.commit_epoch(CITY, _commit("e2", 1, [Visit(A, K1, 6), Visit(A, K2, 5)], retention_s=100))
    assert store.load_state(CITY, [K1, K2], [A]).visited == {A: {(K1, 5), (K1, 6), (K2, 5)}}
    assert store.load_state(CITY, [K2], [A]).visited == {A: {(K2, 5)}}
    clock.now += 101  # every visit expired
    assert store.load_state(CITY, [K1, K2], [A]).visited == {A: set()}
    store.commit_epoch(CITY, _commit("e3", 0, [Visit(A, K1, 7)], retention_s=100))
    assert store.load_state(CITY, [K1, K2], [A]).visited == {A: {(K1, 7)}}
