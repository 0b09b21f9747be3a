"""The fleet-sizing part of the ``Store`` contract (recommendations, history, locks, the solve queue), run
against ``MemoryStore`` and ``RedisStore`` alike."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest

from app.adapters import MemoryStore
from app.ports import FleetRecord, SolveRequest, Store

from .conftest import StoreCase

CITY = "testville"
T0 = 1_700_000_000.125


def published(version: int, interval: int = 470_000, body: str = '{"x": 1}', **kw: object) -> FleetRecord:
    return FleetRecord("published", T0 + version, interval, version=version, body_json=body, **kw)  # type: ignore[arg-type]


def failed(reason: str, interval: int = 470_000, request_id: str | None = None) -> FleetRecord:
    return FleetRecord("failed", T0 + 0.5, interval, reason=reason, request_id=request_id)


@pytest.fixture
def twin(case: StoreCase) -> Callable[[], Store]:
    """Factory of more store objects on the same data (``StoreCase.again``)."""
    return case.again


def test_nothing_published_yet(store: Store) -> None:
    assert store.current_recommendation(CITY) is None
    assert store.recommendation_history(CITY, 10) == []
    assert store.claim_solve_request(CITY) is None


def test_publish_is_a_compare_and_set_on_the_version(store: Store) -> None:
    first = published(1, request_id="req-1")
    result = store.publish_recommendation(CITY, first, 10)
    assert (result.status, result.version) == ("published", 1)
    assert store.current_recommendation(CITY) == first
    for stale in (1, 3):
        result = store.publish_recommendation(CITY, published(stale, body='{"stale": true}'), 10)
        assert (result.status, result.version) == ("version_mismatch", 1)
    assert store.current_recommendation(CITY) == first
    second = published(2, interval=470_001, body='{"ü": "ñ"}')
    result = store.publish_recommendation(CITY, second, 10)
    assert (result.status, result.version) == ("published", 2)
    assert store.current_recommendation(CITY) == second
    assert store.recommendation_history(CITY, 10) == [second, first]


def test_first_publish_must_be_version_one(store: Store) -> None:
    result = store.publish_recommendation(CITY, published(2), 10)
    assert (result.status, result.version) == ("version_mismatch", 0)
    assert store.current_recommendation(CITY) is None and store.recommendation_history(CITY, 5) == []


def test_failures_go_to_the_history_only(store: Store) -> None:
    good = published(1)
    assert store.publish_recommendation(CITY, good, 10).status == "published"
    bad = failed("2 of 12 runs failed: size 20 day 3: ValueError('boom')", request_id="r-9")
    store.record_solve_failure(CITY, bad, 10)
    assert store.current_recommendation(CITY) == good
    assert store.recommendation_history(CITY, 10) == [bad, good]
    assert store.recommendation_history(CITY, 1) == [bad]
    assert store.recommendation_history(CITY, 0) == []


def test_history_is_bounded_newest_first(store: Store) -> None:
    for v in range(1, 6):
        assert store.publish_recommendation(CITY, published(v), 3).status == "published"
    store.record_solve_failure(CITY, failed("late"), 3)
    assert [r.version for r in store.recommendation_history(CITY, 10)] == [None, 5, 4]
    assert store.current_recommendation(CITY) == published(5)


def test_cities_are_independent(store: Store) -> None:
    assert store.publish_recommendation(CITY, published(1), 10).status == "published"
    assert store.current_recommendation("elsewhere") is None
    assert store.publish_recommendation("elsewhere", published(1), 10).status == "published"
    assert store.acquire_lock(CITY, "hour:1", 10.0) is not None
    assert store.acquire_lock("elsewhere", "hour:1", 10.0) is not None


def test_records_are_checked(store: Store) -> None:
    with pytest.raises(ValueError):
        store.publish_recommendation(CITY, failed("x"), 10)
    with pytest.raises(ValueError):
        store.record_solve_failure(CITY, published(1), 10)
    with pytest.raises(ValueError):
        store.publish_recommendation(CITY, published(1), 0)
    with pytest.raises(ValueError):
        store.publish_recommendation(CITY, FleetRecord("published", T0, 1, version=1, body_json=None), 5)
    assert store.current_recommendation(CITY) is None


def test_racing_publishers_publish_once(case: StoreCase, twin: Callable[[], Store]) -> None:
    """Several threads (each with its own connection for Redis) publish version 1 at once."""
    stores = [twin() for _ in range(4)]
    barrier = threading.Barrier(len(stores))
    outcomes: list[str] = []

    def publish(s: Store, me: int) -> None:
        barrier.wait()
        outcomes.append(s.publish_recommendation(CITY, published(1, body=f'{{"me": {me}}}'), 10).status)

    threads = [threading.Thread(target=publish, args=(s, i)) for i, s in enumerate(stores)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(outcomes) == ["published"] + ["version_mismatch"] * 3
    assert len(case.store.recommendation_history(CITY, 10)) == 1


def test_lock_excludes_until_released_by_its_holder(store: Store) -> None:
    token = store.acquire_lock(CITY, "hour:7", 30.0)
    assert token is not None
    assert store.acquire_lock(CITY, "hour:7", 30.0) is None
    assert store.acquire_lock(CITY, "hour:8", 30.0) is not None  # another name is another lock
    assert store.release_lock(CITY, "hour:7", "not-the-token") is False
    assert store.acquire_lock(CITY, "hour:7", 30.0) is None
    assert store.release_lock(CITY, "hour:7", token) is True
    assert store.release_lock(CITY, "hour:7", token) is False
    again = store.acquire_lock(CITY, "hour:7", 30.0)
    assert again is not None and again != token
    with pytest.raises(ValueError):
        store.acquire_lock(CITY, "hour:9", 0.0)


def test_lock_expires_and_the_old_token_cannot_release_the_new_holder(store: Store) -> None:
    old = store.acquire_lock(CITY, "hour:7", 0.05)
    assert old is not None
    time.sleep(0.15)
    new = store.acquire_lock(CITY, "hour:7", 30.0)
    assert new is not None
    assert store.release_lock(CITY, "hour:7", old) is False
    assert store.acquire_lock(CITY, "hour:7", 30.0) is None
    assert store.release_lock(CITY, "hour:7", new) is True


def test_racing_lockers_get_one_token(case: StoreCase, twin: Callable[[], Store]) -> None:
    stores = [twin() for _ in range(6)]
    barrier = threading.Barrier(len(stores))
    tokens: list[str | None] = []

    def grab(s: Store) -> None:
        barrier.wait()
        tokens.append(s.acquire_lock(CITY, "hour:1", 30.0))

    threads = [threading.Thread(target=grab, args=(s,)) for s in stores]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sum(t is not None for t in tokens) == 1


def test_solve_queue_holds_one_pending_request(store: Store) -> None:
    a = SolveRequest("req-a", T0, "tok-…")
    b = SolveRequest("req-b", T0 + 1, None)
    first = store.enqueue_solve_request(CITY, a)
    assert first.created and first.request == a
    joined = store.enqueue_solve_request(CITY, b)
    assert not joined.created and joined.request == a
    assert store.claim_solve_request("elsewhere") is None
    assert store.claim_solve_request(CITY) == a
    assert store.claim_solve_request(CITY) is None
    again = store.enqueue_solve_request(CITY, b)
    assert again.created and again.request == b
    assert store.claim_solve_request(CITY) == b


def test_racing_claims_get_the_request_once(case: StoreCase, twin: Callable[[], Store]) -> None:
    case.store.enqueue_solve_request(CITY, SolveRequest("only", T0))
    stores = [twin() for _ in range(5)]
    barrier = threading.Barrier(len(stores))
    got: list[SolveRequest | None] = []

    def claim(s: Store) -> None:
        barrier.wait()
        got.append(s.claim_solve_request(CITY))

    threads = [threading.Thread(target=claim, args=(s,)) for s in stores]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [g.request_id for g in got if g is not None] == ["only"]


def test_memory_lock_follows_its_clock() -> None:
    now = [100.0]
    clock: Callable[[], float] = lambda: now[0]  # noqa: E731
    store = MemoryStore(clock=clock)
    token = store.acquire_lock(CITY, "hour:1", 10.0)
    assert token is not None
    now[0] = 109.9
    assert store.acquire_lock(CITY, "hour:1", 10.0) is None
    now[0] = 110.0
    assert store.release_lock(CITY, "hour:1", token) is False
    assert store.acquire_lock(CITY, "hour:1", 10.0) is not None
