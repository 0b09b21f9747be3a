"""Lexicographic assignment against brute force over every matching."""

from __future__ import annotations

import numpy as np
import pytest

from services.matching import lexicographic_weights, max_weight_matching
from tests import reference as ref


@pytest.mark.parametrize("seed", range(300))
def test_lexicographic_matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    feasible = rng.random((n, m)) < 0.7
    # few distinct values so that ties in the primary objective are common
    prim = rng.integers(0, 4, size=(n, m))
    sec = rng.integers(0, 6, size=(n, m))
    sense = "min" if seed % 2 == 0 else "max"
    sol = max_weight_matching(lexicographic_weights(feasible, prim, sec, secondary_sense=sense))
    pairs = list(zip(sol.rows.tolist(), sol.cols.tolist(), strict=True))
    assert len({i for i, _ in pairs}) == len(pairs) and len({j for _, j in pairs}) == len(pairs)
    assert all(feasible[i, j] for i, j in pairs)
    p = sum(int(prim[i, j]) for i, j in pairs)
    s = sum(int(sec[i, j]) for i, j in pairs)
    cand = [(i, j) for i in range(n) for j in range(m) if feasible[i, j]]
    prim_of = {x: int(prim[x]) for x in cand}
    sec_of = {x: int(sec[x]) for x in cand}
    assert (p, s) == ref.lexi_best(cand, prim_of, sec_of, sense=sense, tol=0.0)


def test_count_then_wait_prefers_more_matches_over_less_wait() -> None:
    # taxi 0 can serve rider 0 (wait 1) or rider 1 (wait 100); taxi 1 only rider 0 (wait 50).
    feasible = np.array([[True, True], [True, False]])
    sec = np.array([[1, 100], [50, 0]])
    sol = max_weight_matching(
        lexicographic_weights(feasible, feasible.astype(np.int64), sec, secondary_sense="min")
    )
    assert sorted(zip(sol.rows.tolist(), sol.cols.tolist(), strict=True)) == [(0, 1), (1, 0)]


def test_zero_primary_pairs_are_left_out_when_minimizing() -> None:
    feasible = np.array([[True]])
    sol = max_weight_matching(
        lexicographic_weights(feasible, np.array([[0]]), np.array([[5]]), secondary_sense="min")
    )
    assert len(sol.rows) == 0


def test_too_large_weights_are_refused() -> None:
    with pytest.raises(ValueError, match="too large"):
        max_weight_matching(np.array([[2**49, 2**49], [2**49, 2**49]], dtype=np.int64))


def test_empty() -> None:
    sol = max_weight_matching(np.zeros((0, 3), dtype=np.int64))
    assert sol.total == 0 and len(sol.rows) == 0
