"""Fleet workers' heartbeats and the peek at the solve queue, part of the ``Store`` contract: run against
``MemoryStore``, ``RedisStore`` and ``RedisStore`` on a Redis Cluster alike."""

from __future__ import annotations

import time

import pytest

from app.ports import SolveProgress, SolveRequest, Store, WorkerBeat

from .conftest import StoreCase

CITY = "testville"
T0 = 1_700_000_000.125
KEEP_S = 3600.0


def beat(worker: str, seen_at_s: float, **kw: object) -> WorkerBeat:
    base: dict[str, object] = {
        "started_at_s": T0 - 60.0,
        "host": "box-1",
        "pid": 4242,
        "embedded": False,
        "poll_s": 5.0,
    }
    return WorkerBeat(worker, seen_at_s, **(base | kw))  # type: ignore[arg-type]


def test_no_beats_and_no_pending_request_at_first(store: Store) -> None:
    assert store.worker_beats(CITY) == []
    assert store.pending_solve_request(CITY) is None


def test_the_pending_request_is_read_without_claiming_it(store: Store) -> None:
    request = SolveRequest("req-a", T0, "tok-abc")
    store.enqueue_solve_request(CITY, request)
    assert store.pending_solve_request(CITY) == request
    assert store.pending_solve_request(CITY) == request
    assert store.pending_solve_request("elsewhere") is None
    assert store.claim_solve_request(CITY) == request
    assert store.pending_solve_request(CITY) is None


def test_a_beat_round_trips_and_replaces_its_workers_previous_one(case: StoreCase) -> None:
    store = case.store
    progress = SolveProgress(470_123, "request", "req-9", T0 - 12.5, 60, 17, 5, 2, 1)
    first = beat("w1", T0, solving=progress, next_interval=470_124, next_due_at_s=T0 + 1800.0)
    store.record_worker_beat(CITY, first, KEEP_S)
    assert store.worker_beats(CITY) == [first]
    assert case.again().worker_beats(CITY) == [first]  # another client (process) reads the same
    later = beat("w1", T0 + 2.0, embedded=True)  # idle now: no solve, no schedule
    store.record_worker_beat(CITY, later, KEEP_S)
    assert store.worker_beats(CITY) == [later]
    assert store.worker_beats("elsewhere") == []


def test_every_worker_keeps_its_own_beat_newest_first(store: Store) -> None:
    a, b = beat("w-a", T0 + 5.0), beat("w-b", T0 + 9.0, host="box-2", pid=7)
    store.record_worker_beat(CITY, b, KEEP_S)
    store.record_worker_beat(CITY, a, KEEP_S)
    assert store.worker_beats(CITY) == [b, a]
    a2 = beat("w-a", T0 + 11.0)
    store.record_worker_beat(CITY, a2, KEEP_S)
    assert store.worker_beats(CITY) == [a2, b]


def test_beats_seen_longer_than_keep_before_a_new_one_are_dropped(store: Store) -> None:
    old, mid = beat("gone", T0), beat("mid", T0 + 40.0)
    store.record_worker_beat(CITY, old, 100.0)
    store.record_worker_beat(CITY, mid, 100.0)
    new = beat("new", T0 + 120.0)
    store.record_worker_beat(CITY, new, 100.0)  # cutoff T0 + 20: "gone" goes, "mid" stays
    assert store.worker_beats(CITY) == [new, mid]


def test_a_citys_beats_are_forgotten_keep_s_after_the_last_one(store: Store) -> None:
    store.record_worker_beat(CITY, beat("w1", T0), 0.4)
    store.record_worker_beat("other", beat("w1", T0), 3600.0)
    assert len(store.worker_beats(CITY)) == 1
    time.sleep(0.7)
    assert store.worker_beats(CITY) == []
    assert len(store.worker_beats("other")) == 1


def test_a_reset_of_the_epoch_stream_keeps_the_beats(store: Store) -> None:
    b = beat("w1", T0)
    store.record_worker_beat(CITY, b, KEEP_S)
    store.reset_epochs(CITY)
    assert store.worker_beats(CITY) == [b]


@pytest.mark.parametrize("keep_s", [0.0, -1.0])
def test_a_non_positive_keep_is_refused_and_writes_nothing(store: Store, keep_s: float) -> None:
    with pytest.raises(ValueError, match="keep_s"):
        store.record_worker_beat(CITY, beat("w1", T0), keep_s)
    assert store.worker_beats(CITY) == []
