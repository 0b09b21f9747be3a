"""A commit's visits applied to the Redis store's mirror (``CityMirror.apply_visits``) all at once give what
applying them one visit at a time gives (the rule the commit script follows: a cell new to a held visit set
counts once more; a set not held, or held past its deadline, makes its interval's counts unknown), on random
mirrors and visits with repeats, expired entries and sets the mirror lacks."""

from __future__ import annotations

import random
from collections.abc import Sequence

import pytest

from app.adapters.redis_mirror import CityMirror
from services.model import IntervalKey, TaxiId, Visit

NOW, DEADLINE = 100.0, 500.0


def one_at_a_time(m: CityMirror, visits: Sequence[Visit], now: float, deadline: float) -> None:
    """The rule, visit by visit, copying an entry at every change."""
    counts, sets = m.counts, m.visits
    for v in visits:
        key = (v.interval, v.taxi_id)
        have = sets.get(key)
        if have is None or not have[0] > now:
            sets.pop(key, None)
            counts.pop(v.interval, None)
            continue
        pair = (v.interval, int(v.cell))
        if pair in have[1]:
            sets[key] = (deadline, have[1])
            continue
        sets[key] = (deadline, have[1] | {pair})
        hit = counts.get(v.interval)
        if hit is not None and not hit[0] > now:
            counts.pop(v.interval)
        elif hit is not None:
            cells = dict(hit[1])
            cells[int(v.cell)] = cells.get(int(v.cell), 0) + 1
            counts[v.interval] = (deadline, cells)


def _mirror(rng: random.Random, ks: list[IntervalKey], taxis: list[TaxiId]) -> CityMirror:
    m = CityMirror("r", 1)
    for k in ks:
        if rng.random() < 0.8:
            alive = NOW + 10 if rng.random() < 0.85 else NOW - 1
            m.counts[k] = (alive, {c: rng.randint(1, 3) for c in rng.sample(range(8), rng.randint(0, 5))})
        for t in taxis:
            if rng.random() < 0.8:
                alive = NOW + 10 if rng.random() < 0.9 else NOW - 1
                cells = rng.sample(range(8), rng.randint(0, 4))
                m.visits[(k, t)] = (alive, frozenset((k, c) for c in cells))
    return m


@pytest.mark.parametrize("seed", range(300))
def test_all_at_once_is_one_at_a_time(seed: int) -> None:
    rng = random.Random(seed)
    ks = [IntervalKey(480 + i) for i in range(rng.randint(1, 3))]
    taxis = [TaxiId(f"t{i}") for i in range(rng.randint(1, 4))]
    m = _mirror(rng, ks, taxis)
    visits = [Visit(rng.choice(taxis), rng.choice(ks), rng.randrange(8)) for _ in range(rng.randint(0, 25))]
    want = CityMirror("r", 1, dict(m.counts), dict(m.visits))
    got = CityMirror("r", 1, dict(m.counts), dict(m.visits))
    before = {k: dict(v[1]) for k, v in m.counts.items()}
    one_at_a_time(want, visits, NOW, DEADLINE)
    got.apply_visits(visits, NOW, DEADLINE)
    assert got.counts == want.counts and got.visits == want.visits
    assert {k: dict(v[1]) for k, v in m.counts.items()} == before  # entries handed out are never changed
