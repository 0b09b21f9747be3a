"""The Redis store's state mirror (app/adapters/redis_mirror.py): whatever interleaving of epochs, task
registrations, replays and refused commits several store objects on one Redis (or Redis Cluster) make,
every load equals the load of a store that holds no mirror, and the counts equal the ledger's."""

from __future__ import annotations

import dataclasses
import random
import time
from typing import Any

import pytest

from app.adapters import RedisStore
from app.ports import CityState, Store
from services.ledger import Ledger, apply_decision
from services.model import IntervalKey, Task, TaskId, TaskStatus, TaxiId, Visit

from .conftest import StoreCase
from .test_store_contract import CITY, T0, commit, task

STATUSES: tuple[TaskStatus, ...] = ("assigned", "completed", "expired")
KS = [IntervalKey(480 + i) for i in range(4)]
TAXIS = [TaxiId(f"taxi-{i}") for i in range(5)]


def _sorted(state: CityState) -> CityState:
    return dataclasses.replace(state, tasks=sorted(state.tasks, key=lambda t: t.id))


def _fresh_load(case: StoreCase, ks: list[IntervalKey], taxis: list[TaxiId]) -> CityState:
    """The load of a store object made now: no mirror."""
    return _sorted(case.again().load_state(CITY, ks, taxis))


def _check_all(case: StoreCase, stores: list[Store], ledger: Ledger, rng: random.Random) -> None:
    ks = sorted(rng.sample(KS, rng.randint(1, len(KS))))
    taxis = rng.sample(TAXIS, rng.randint(1, len(TAXIS)))
    want = _fresh_load(case, ks, taxis)
    for k in ks:
        assert want.counts[k] == {c: n for c, n in ledger.counts.get(k, {}).items() if n}
    for s in stores:
        assert _sorted(s.load_state(CITY, ks, taxis)) == want


def _epoch(store: Store, ledger: Ledger, rng: random.Random, n: int, at: float) -> str:
    """One epoch on ``store``: load what it reads (some intervals and taxis), commit visits and task
    updates computed on that version; the ledger follows the commits made."""
    ks = sorted(rng.sample(KS, rng.randint(1, len(KS))))
    taxis = rng.sample(TAXIS, rng.randint(1, len(TAXIS)))
    state = store.load_state(CITY, ks, taxis, visits_from=ks[0])
    visits = [Visit(rng.choice(taxis), rng.choice(ks), rng.randrange(6)) for _ in range(rng.randint(0, 6))]
    updates: list[Task] = []
    for t in rng.sample(state.tasks, min(len(state.tasks), rng.randint(0, 2))):
        status = rng.choice(STATUSES)
        updates.append(dataclasses.replace(t, status=status, taxi_id=rng.choice(taxis)))
    c = commit(f"e{n}", version=state.version, time_s=at, visits=visits, tasks=updates)
    out = store.commit_epoch(CITY, dataclasses.replace(c, nonce=f"n{n}"))
    if out.status == "committed":
        apply_decision(ledger, c.visits, c.task_updates)
    return out.status


@pytest.mark.parametrize(
    "make_case",
    [pytest.param("redis", marks=pytest.mark.redis), pytest.param("redis-cluster", marks=pytest.mark.redis)],
    indirect=True,  # the memory store holds no mirror: its every object is the one store
)
@pytest.mark.parametrize("seed", range(4))
def test_store_objects_interleaving_epochs_load_what_redis_holds(make_case: Any, seed: int) -> None:
    """Three store objects (three API processes) post epochs, register tasks, replay and lose races in a
    random order; after each step every one of them loads what a store without a mirror loads."""
    rng = random.Random(seed)
    case: StoreCase = make_case()
    stores = [case.store, case.again(), case.again()]
    held = [_count_held(s) for s in stores if isinstance(s, RedisStore)]
    assert len(held) == 3
    ledger = Ledger()
    n, at = 0, T0
    for step in range(40):
        store = rng.choice(stores)
        action = rng.random()
        if action < 0.2:
            new = [task(f"p{step}-{i}", node=i) for i in range(rng.randint(1, 3))]
            store.put_tasks(CITY, new)
            ledger.tasks.update({t.id: t for t in new})
        elif action < 0.3 and n:
            # a replay of an earlier epoch id: a duplicate, nothing applied
            old = commit(f"e{rng.randrange(n)}", version=0, time_s=at, visits=[Visit(TAXIS[0], KS[0], 1)])
            assert store.commit_epoch(CITY, old).status in ("duplicate", "version_mismatch")
        elif action < 0.4:
            # refused: a version this store read before someone else committed
            version = store.load_state(CITY, KS[:1], TAXIS[:1]).version
            before = _fresh_load(case, KS, TAXIS)
            stale = commit("late", version=version + 1, time_s=at, visits=[Visit(TAXIS[1], KS[1], 2)])
            assert store.commit_epoch(CITY, stale).status == "version_mismatch"
            assert _fresh_load(case, KS, TAXIS) == before
        else:
            at += 200.0
            if _epoch(store, ledger, rng, n, at) == "committed":
                n += 1
        _check_all(case, stores, ledger, rng)
    assert sum(h[0] for h in held) > 0  # the mirrors were read, not only dropped


def _count_held(store: RedisStore) -> list[int]:
    """A counter of the loads ``store`` answered from its mirror (the script found its revision current)."""
    count = [0]
    real = store._eval

    def spy(script: str, keys: Any, args: Any) -> Any:
        reply = real(script, keys, args)
        if script == "load_state" and args[1] and reply[2] != "stale":
            count[0] += 1
        return reply

    store._eval = spy  # type: ignore[method-assign]
    return count


def test_the_mirror_is_read_instead_of_redis(make_redis_store: Any) -> None:
    """After its own commit a store's next load of the same keys reads none of them; after another
    store's commit the script finds the mirror stale and the store reads every key again. (A city no
    commit has touched has no revision: its first commit is made without a mirror.)"""
    store: RedisStore = make_redis_store()
    other = RedisStore(store._url, prefix=store.prefix)
    rows: list[tuple[int, bool]] = []  # per load script: the count and visit keys asked for, found stale
    real = store._eval

    def spy(script: str, keys: Any, args: Any) -> Any:
        reply = real(script, keys, args)
        if script == "load_state":
            rows.append((len(keys) - 3, reply[2] == "stale"))
        return reply

    store._eval = spy  # type: ignore[method-assign]
    try:
        assert store.commit_epoch(CITY, commit("e0", version=0)).status == "committed"
        store.put_tasks(CITY, [task("p1")])
        state = store.load_state(CITY, KS, TAXIS)
        assert rows[-1] == (len(KS) + len(KS) * len(TAXIS), False)
        c = commit("e1", version=state.version, visits=[Visit(TAXIS[0], KS[0], 3)], tasks=[task("p1")])
        assert store.commit_epoch(CITY, c).status == "committed"
        mine = store.load_state(CITY, KS, TAXIS)
        assert rows[-1] == (0, False)
        assert mine.counts[KS[0]] == {3: 1} and [t.id for t in mine.tasks] == [TaskId("p1")]
        c2 = commit("e2", version=2, time_s=T0 + 1, visits=[Visit(TAXIS[1], KS[0], 3)])
        assert other.commit_epoch(CITY, c2).status == "committed"
        theirs = store.load_state(CITY, KS, TAXIS)
        assert rows[-2:] == [(0, True), (len(KS) + len(KS) * len(TAXIS), False)]
        assert theirs.counts[KS[0]] == {3: 2} and theirs.version == 3
    finally:
        other.close()


def test_a_registration_adds_its_tasks_to_the_mirror(make_redis_store: Any) -> None:
    """A store's own registration leaves its mirror's open tasks current (the next load reads no task);
    another store's registration makes it read them again; either way the load holds every registered
    task."""
    store: RedisStore = make_redis_store()
    other = RedisStore(store._url, prefix=store.prefix)
    read_tasks: list[bool] = []  # per load script: whether it sent the open tasks
    real = store._eval

    def spy(script: str, keys: Any, args: Any) -> Any:
        reply = real(script, keys, args)
        if script == "load_state" and reply[2] != "stale":
            read_tasks.append(reply[2] is not None)
        return reply

    store._eval = spy  # type: ignore[method-assign]
    try:
        store.put_tasks(CITY, [task("p0")])
        state = store.load_state(CITY, KS, TAXIS)
        assert read_tasks[-1]
        c = commit("e1", version=state.version, tasks=[dataclasses.replace(task("p0"), status="assigned")])
        assert store.commit_epoch(CITY, c).status == "committed"
        store.load_state(CITY, KS, TAXIS)  # the city has a revision now: this load starts the mirror
        store.put_tasks(CITY, [task("p1"), task("p2")])
        mine = store.load_state(CITY, KS, TAXIS)
        assert read_tasks[-1] is False
        assert [(t.id, t.status) for t in mine.tasks] == [
            ("p0", "assigned"),
            ("p1", "pending"),
            ("p2", "pending"),
        ]
        other.put_tasks(CITY, [task("p3")])
        theirs = store.load_state(CITY, KS, TAXIS)
        assert read_tasks[-1] is True and [t.id for t in theirs.tasks] == ["p0", "p1", "p2", "p3"]
        assert _sorted(theirs) == _sorted(
            RedisStore(store._url, prefix=store.prefix).load_state(CITY, KS, TAXIS)
        )
    finally:
        other.close()


def test_a_commit_whose_reply_was_lost_drops_the_mirror(make_redis_store: Any) -> None:
    """The same commit sent again (its nonce found) is answered without the revisions: the store cannot
    know what its mirror should hold, so it reads everything again."""
    store: RedisStore = make_redis_store()
    assert store.commit_epoch(CITY, commit("e0", version=0)).status == "committed"
    store.load_state(CITY, KS, TAXIS)
    first = dataclasses.replace(commit("e1", version=1, visits=[Visit(TAXIS[0], KS[0], 5)]), nonce="n-1")
    assert store.commit_epoch(CITY, first).status == "committed"
    store.load_state(CITY, KS, TAXIS)
    assert store._mirrors
    assert store.commit_epoch(CITY, first).status == "committed"
    assert not store._mirrors
    assert store.load_state(CITY, KS, TAXIS).counts[KS[0]] == {5: 1}


def test_mirrored_keys_are_read_again_before_they_can_expire(make_redis_store: Any) -> None:
    """A commit with a retention of 6 s: its keys are held by the mirror for at most 1 s (the margin is
    5 s), read again while they live, and found gone once Redis expired them."""
    store: RedisStore = make_redis_store()
    assert store.commit_epoch(CITY, commit("e0", version=0)).status == "committed"
    store.load_state(CITY, KS, TAXIS)
    c = commit("e1", version=1, visits=[Visit(TAXIS[0], KS[0], 5)], retention_s=6)
    assert store.commit_epoch(CITY, c).status == "committed"
    assert store._mirrors[CITY].count(KS[0], time.monotonic()) is not None
    time.sleep(1.2)
    assert store._mirrors[CITY].count(KS[0], time.monotonic()) is None
    assert store.load_state(CITY, KS, TAXIS).counts[KS[0]] == {5: 1}
    time.sleep(5.5)
    state = store.load_state(CITY, KS, TAXIS)
    assert state.counts[KS[0]] == {} and state.visited[TAXIS[0]] == set()


def test_a_reset_by_another_store_is_seen(make_redis_store: Any) -> None:
    store: RedisStore = make_redis_store()
    other = RedisStore(store._url, prefix=store.prefix)
    try:
        store.put_tasks(CITY, [task("p1")])
        state = store.load_state(CITY, KS, TAXIS)
        c = commit("e1", version=state.version, visits=[Visit(TAXIS[0], KS[0], 5)])
        assert store.commit_epoch(CITY, c).status == "committed"
        assert store.load_state(CITY, KS, TAXIS).counts[KS[0]] == {5: 1}
        assert other.reset_epochs(CITY) > 0
        state = store.load_state(CITY, KS, TAXIS)
        assert (state.version, state.counts[KS[0]], state.tasks) == (0, {}, [])
    finally:
        other.close()
