"""Code run in separate OS processes (multiprocessing 'spawn') by the concurrency tests."""

from __future__ import annotations

import random
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.queues import Queue
from multiprocessing.sharedctypes import Synchronized
from multiprocessing.synchronize import Barrier
from typing import Any

from app.adapters import RedisStore
from app.ports import CityState, EpochCommit, Store
from services.model import IntervalKey, Task, TaskId, TaxiId, Visit

CITY = "racetown"
T0 = 1_700_000_000.0


@dataclass(frozen=True)
class EpochSpec:
    """An epoch whose outcome depends on the state it is solved on (like a real dispatch)."""

    index: int
    taxi: TaxiId
    interval: IntervalKey
    candidates: tuple[int, ...]
    fixed_cell: int


def decide(spec: EpochSpec, state: CityState) -> EpochCommit:
    """Send the taxi through the least-counted candidate cell; log the version solved on in a task."""
    counts = state.counts.get(spec.interval, {})
    chosen = min(spec.candidates, key=lambda cell: (counts.get(cell, 0), cell))
    return EpochCommit(
        epoch_id=f"epoch-{spec.index}",
        body_hash=f"hash-{spec.index}",
        time_s=T0,
        expected_version=state.version,
        visits=[Visit(spec.taxi, spec.interval, chosen), Visit(spec.taxi, spec.interval, spec.fixed_cell)],
        task_updates=[Task(TaskId(f"log-{spec.index}"), node=state.version, scheduled_at_s=T0)],
        response_json=f'{{"chosen": {chosen}}}',
    )


def solve_and_commit(
    store: Store, spec: EpochSpec, pause: Callable[[], float] | None = None
) -> tuple[int, int]:
    """Load, decide, commit; on ``version_mismatch`` load and solve again. Returns (version, mismatches)."""
    mismatches = 0
    while True:
        state = store.load_state(CITY, [spec.interval], [spec.taxi])
        commit = decide(spec, state)
        if pause is not None:
            time.sleep(pause())  # widen the window between read and commit so the processes collide
        result = store.commit_epoch(CITY, commit)
        if result.status == "version_mismatch":
            mismatches += 1
            continue
        if result.status != "committed" or result.new_version is None:
            raise AssertionError(f"epoch {spec.index}: unexpected {result}")
        return result.new_version, mismatches


def loop_worker(
    url: str,
    prefix: str,
    specs: list[EpochSpec],
    cursor: Synchronized[int],
    barrier: Barrier,
    seed: int,
    out: Queue[Any],
) -> None:
    """Take epochs from the shared list in order and commit each, retrying on version mismatch."""
    try:
        store = RedisStore(url, prefix=prefix)
        rng = random.Random(seed)
        committed: list[tuple[int, int]] = []
        mismatches = 0
        barrier.wait(timeout=60)
        while True:
            with cursor.get_lock():
                i = cursor.value
                if i >= len(specs):
                    break
                cursor.value = i + 1
            version, missed = solve_and_commit(store, specs[i], pause=lambda: rng.uniform(0, 0.004))
            committed.append((version, i))
            mismatches += missed
        store.close()
        out.put(("ok", committed, mismatches))
    except BaseException:
        out.put(("error", traceback.format_exc(), 0))


def race_worker(url: str, prefix: str, me: int, rounds: int, barrier: Barrier, out: Queue[Any]) -> None:
    """Each round, commit the same epoch id as every other process, with visits of its own taxi."""
    try:
        store = RedisStore(url, prefix=prefix)
        statuses: list[tuple[str, str | None]] = []
        for r in range(rounds):
            commit = EpochCommit(
                epoch_id=f"race-{r}",
                body_hash=f"hash-{r}",
                time_s=T0 + r,
                expected_version=r,
                visits=[Visit(TaxiId(f"taxi-{me}"), IntervalKey(r), cell) for cell in (1, 2)],
                task_updates=[],
                response_json=f'{{"winner": {me}}}',
            )
            barrier.wait(timeout=60)
            result = store.commit_epoch(CITY, commit)
            stored = result.stored.response_json if result.stored else None
            statuses.append((result.status, stored))
        store.close()
        out.put(("ok", statuses, me))
    except BaseException:
        out.put(("error", traceback.format_exc(), me))
