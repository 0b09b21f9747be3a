"""Exactly-once and serialization across real OS processes sharing one Redis server."""

from __future__ import annotations

import multiprocessing as mp
import queue
import random
import time
from collections.abc import Callable
from typing import Any

import pytest

from app.adapters import MemoryStore, RedisStore
from services.model import IntervalKey, TaxiId

from . import _workers as w

pytestmark = [pytest.mark.redis, pytest.mark.slow]

_JOIN_S = 120


def _run(target: Callable[..., None], per_process_args: list[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
    """Start one spawned process per argument tuple (the queue is appended), collect one report each."""
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    procs = [ctx.Process(target=target, args=(*args, out), daemon=True) for args in per_process_args]
    for p in procs:
        p.start()
    reports: list[tuple[Any, ...]] = []
    deadline = time.monotonic() + _JOIN_S
    try:
        while len(reports) < len(procs):
            try:
                reports.append(out.get(timeout=0.5))
            except queue.Empty:
                dead = [p.exitcode for p in procs if p.exitcode not in (None, 0)]
                assert not dead, f"a worker died without reporting (exit codes {dead})"
                assert time.monotonic() < deadline, f"workers did not report within {_JOIN_S} s"
        for p in procs:
            p.join(timeout=_JOIN_S)
            assert p.exitcode == 0, f"worker exited with {p.exitcode}"
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
                p.join(5)
    errors = [r[1] for r in reports if r[0] == "error"]
    assert not errors, "\n".join(errors)
    return reports


@pytest.mark.parametrize("n_procs", [2, 4])
def test_processes_racing_on_one_epoch_commit_it_once(
    redis_url: str, redis_prefix: str, n_procs: int
) -> None:
    rounds = 6
    barrier = mp.get_context("spawn").Barrier(n_procs)
    reports = _run(w.race_worker, [(redis_url, redis_prefix, me, rounds, barrier) for me in range(n_procs)])
    store = RedisStore(redis_url, prefix=redis_prefix)
    try:
        for r in range(rounds):
            outcomes = [(me, statuses[r]) for _, statuses, me in reports]
            winners = [me for me, (status, _) in outcomes if status == "committed"]
            assert len(winners) == 1, outcomes
            (winner,) = winners
            stored = store.get_epoch(w.CITY, f"race-{r}")
            assert stored is not None and stored.response_json == f'{{"winner": {winner}}}'
            for me, (status, response) in outcomes:
                if me != winner:
                    assert (status, response) == ("duplicate", stored.response_json)
            # the winner's visits, applied once; nobody else's
            assert store.interval_counts(w.CITY, IntervalKey(r)) == {1: 1, 2: 1}
            taxis = [TaxiId(f"taxi-{me}") for me in range(n_procs)]
            visited = store.load_state(w.CITY, [IntervalKey(r)], taxis).visited
            assert {t for t, cells in visited.items() if cells} == {TaxiId(f"taxi-{winner}")}
        assert store.load_state(w.CITY, [], []).version == rounds
    finally:
        store.close()


def _specs(n: int, seed: int) -> list[w.EpochSpec]:
    rng = random.Random(seed)
    return [
        w.EpochSpec(
            index=i,
            taxi=TaxiId(f"taxi-{rng.randrange(5)}"),
            interval=IntervalKey(rng.randrange(3)),
            candidates=tuple(rng.sample(range(8), 3)),
            fixed_cell=rng.randrange(8),
        )
        for i in range(n)
    ]


def test_two_processes_load_commit_loops_serialize(redis_url: str, redis_prefix: str) -> None:
    specs = _specs(40, seed=7)
    ctx = mp.get_context("spawn")
    cursor = ctx.Value("i", 0)
    barrier = ctx.Barrier(2)
    reports = _run(
        w.loop_worker, [(redis_url, redis_prefix, specs, cursor, barrier, seed) for seed in (1, 2)]
    )
    committed = sorted(pair for _, pairs, _ in reports for pair in pairs)
    assert sum(missed for _, _, missed in reports) > 0, "the processes never collided: retry path untested"
    assert [version for version, _ in committed] == list(range(1, len(specs) + 1))
    assert sorted(i for _, i in committed) == list(range(len(specs)))

    # a single process committing the same epochs in the order they were committed reaches the same state
    sequential = MemoryStore()
    for version, i in committed:
        assert w.solve_and_commit(sequential, specs[i]) == (version, 0)
    ks = [IntervalKey(k) for k in range(3)]
    taxis = [TaxiId(f"taxi-{t}") for t in range(5)]
    store = RedisStore(redis_url, prefix=redis_prefix)
    try:
        assert store.load_state(w.CITY, ks, taxis) == sequential.load_state(w.CITY, ks, taxis)
        assert store.list_intervals(w.CITY) == sequential.list_intervals(w.CITY)
        # every task logs the version its epoch was solved on: one less than the version it committed as
        assert {t.id: t.node for t in store.list_tasks(w.CITY)} == {
            f"log-{i}": version - 1 for version, i in committed
        }
    finally:
        store.close()


def test_two_processes_in_index_order_match_a_sequential_run(redis_url: str, redis_prefix: str) -> None:
    """With order-independent epochs, the result equals the plain sequential run over the list."""
    specs = [
        w.EpochSpec(i, TaxiId(f"taxi-{i % 3}"), IntervalKey(i % 2), (i % 5,), (i * 3) % 7) for i in range(30)
    ]
    ctx = mp.get_context("spawn")
    cursor, barrier = ctx.Value("i", 0), ctx.Barrier(2)
    reports = _run(
        w.loop_worker, [(redis_url, redis_prefix, specs, cursor, barrier, seed) for seed in (3, 4)]
    )
    assert sum(len(pairs) for _, pairs, _ in reports) == len(specs)
    sequential = MemoryStore()
    for spec in specs:
        w.solve_and_commit(sequential, spec)
    ks, taxis = [IntervalKey(0), IntervalKey(1)], [TaxiId(f"taxi-{t}") for t in range(3)]
    store = RedisStore(redis_url, prefix=redis_prefix)
    try:
        ours, theirs = store.load_state(w.CITY, ks, taxis), sequential.load_state(w.CITY, ks, taxis)
        assert (ours.version, ours.counts, ours.visited) == (theirs.version, theirs.counts, theirs.visited)
    finally:
        store.close()


def test_threads_on_one_memory_store_serialize() -> None:
    """The embedded store under the API's threadpool: same serialization guarantee, one lock."""
    import threading

    specs = _specs(60, seed=11)
    store = MemoryStore()
    lock, cursor = threading.Lock(), iter(range(len(specs)))
    committed: list[tuple[int, int]] = []

    def loop(seed: int) -> None:
        rng = random.Random(seed)
        while True:
            with lock:
                i = next(cursor, None)
            if i is None:
                return
            version, _ = w.solve_and_commit(store, specs[i], pause=lambda: rng.uniform(0, 0.001))
            with lock:
                committed.append((version, i))

    threads = [threading.Thread(target=loop, args=(seed,)) for seed in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    committed.sort()
    assert [v for v, _ in committed] == list(range(1, len(specs) + 1))
    sequential = MemoryStore()
    for _, i in committed:
        w.solve_and_commit(sequential, specs[i])
    ks, taxis = [IntervalKey(k) for k in range(3)], [TaxiId(f"taxi-{t}") for t in range(5)]
    assert store.load_state(w.CITY, ks, taxis) == sequential.load_state(w.CITY, ks, taxis)
