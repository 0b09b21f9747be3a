"""The exact lexicographic assignment against independent exact formulations.

* brute force over every matching (Python integers) on small instances, magnitudes up to 2**48;
* networkx's blossom matching with the single exact weight ``primary * K - secondary`` (Python integers,
  ``K`` above any secondary total) on medium instances with realistic magnitudes;
* scipy's dense ``linear_sum_assignment`` with that weight where it is exact in float64 (totals below
  2**53), at 300 x 300 and at the service's limits (2000 riders x 5000 taxis).
"""

from __future__ import annotations

import itertools

import networkx as nx
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from services.matching.assignment import lexicographic_assignment
from tests.reference import all_matchings


def random_pairs(rng, n_rows, n_cols, density):
    mask = rng.random((n_rows, n_cols)) < density
    rows, cols = np.nonzero(mask)
    return rows.astype(np.int64), cols.astype(np.int64)


def brute(rows, cols, p, s, sense):
    best = None
    for m in all_matchings(list(zip(rows.tolist(), cols.tolist(), strict=True))):
        idx = [k for k, pr in enumerate(zip(rows.tolist(), cols.tolist(), strict=True)) if pr in m]
        tp = sum(int(p[k]) for k in idx)
        ts = sum(int(s[k]) for k in idx)
        key = (tp, -ts if sense == "min" else ts)
        if best is None or key > best:
            best = key
    assert best is not None
    return best[0], (-best[1] if sense == "min" else best[1])


def check_matching(a, rows, cols):
    assert len(set(a.rows.tolist())) == len(a.rows)
    assert len(set(a.cols.tolist())) == len(a.cols)
    assert np.array_equal(rows[a.pair], a.rows) and np.array_equal(cols[a.pair], a.cols)


@pytest.mark.parametrize("seed", range(60))
def test_brute_force_small(seed):
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 6)), int(rng.integers(1, 6))
    rows, cols = random_pairs(rng, n, m, 0.6)
    k = len(rows)
    big = 2**48 if seed % 2 else 10
    # ties on purpose: few distinct primaries, some zero
    p = rng.integers(0, 4, size=k).astype(np.int64) * (big // 4 + 1)
    s = rng.integers(0, 5, size=k).astype(np.int64) * (2**30 if seed % 3 == 0 else 1)
    sense = "min" if seed % 4 else "max"
    if sense == "min":
        keep = p > 0  # Step 1 gives only pairs of positive gain
        rows, cols, p, s = rows[keep], cols[keep], p[keep], s[keep]
    a = lexicographic_assignment(rows, cols, p, s, secondary_sense=sense)
    check_matching(a, rows, cols)
    assert (a.primary, a.secondary) == brute(rows, cols, p, s, sense)


def exact_by_blossom(rows, cols, p, s):
    """max sum(p), then min sum(s): one integer weight per edge, networkx's exact blossom algorithm."""
    k_big = int(s.sum()) + 1
    g = nx.Graph()
    for r, c, pp, ss in zip(rows.tolist(), cols.tolist(), p.tolist(), s.tolist(), strict=True):
        g.add_edge(("r", r), ("c", c), weight=int(pp) * k_big - int(ss))
    mate = nx.max_weight_matching(g, maxcardinality=False)
    index = {(r, c): i for i, (r, c) in enumerate(zip(rows.tolist(), cols.tolist(), strict=True))}
    chosen = [index[(a[1], b[1]) if a[0] == "r" else (b[1], a[1])] for a, b in mate]
    return sum(int(p[i]) for i in chosen), sum(int(s[i]) for i in chosen)


@pytest.mark.parametrize("seed", range(4))
def test_realistic_magnitudes_against_blossom(seed):
    """Gains in 2**-48 units of the kind Step 1 makes: a few first visits and many tiny marginal terms of
    cells counted by dozens of taxis, with exact ties between pairs that share a trip."""
    rng = np.random.default_rng(100 + seed)
    n, m = 40, 60
    rows, cols = random_pairs(rng, n, m, 0.15)
    unit = 2.0**-48
    lam = rng.integers(0, 60, size=len(rows))
    term = (lam + 1.0) ** 0.2 - lam**0.2  # one marginal term per pair, as small as 1e-3 of a first visit
    trip = rng.integers(1, 4, size=n)[rows]  # riders' trips cross 1-3 such cells
    p = np.ceil(term / unit).astype(np.int64) * trip
    s = (rng.integers(30, 400, size=len(rows)) * 1_000_000).astype(np.int64)  # waits in microseconds
    a = lexicographic_assignment(rows, cols, p, s, secondary_sense="min")
    check_matching(a, rows, cols)
    assert (a.primary, a.secondary) == exact_by_blossom(rows, cols, p, s)


def exact_by_lsa(n, m, rows, cols, p, s, sense):
    """scipy's assignment with the weight p*K -/+ s on a dense matrix (0 = no pair), exact while every
    total stays below 2**53 (asserted)."""
    sign = -1 if sense == "min" else 1
    k_big = int(np.abs(s).sum()) + 1
    w = p.astype(object) * k_big + sign * s.astype(object)
    assert int(max(w.max(), 0)) * min(n, m) < 2**53
    dense = np.zeros((n, m))
    dense[rows, cols] = w.astype(np.float64)
    r, c = linear_sum_assignment(dense, maximize=True)
    keep = dense[r, c] > 0
    index = {(a, b): i for i, (a, b) in enumerate(zip(rows.tolist(), cols.tolist(), strict=True))}
    chosen = [index[(a, b)] for a, b in zip(r[keep].tolist(), c[keep].tolist(), strict=True)]
    return sum(int(p[i]) for i in chosen), sum(int(s[i]) for i in chosen)


@pytest.mark.parametrize(
    ("n", "m", "density", "sense"),
    [(300, 300, 0.05, "min"), (300, 300, 1.0, "max"), (800, 1500, 0.02, "min")],
)
def test_against_dense_lsa(n, m, density, sense):
    rng = np.random.default_rng(n + m)
    rows, cols = random_pairs(rng, n, m, density)
    p = (
        rng.integers(1, 2**12, size=len(rows)).astype(np.int64)
        if sense == "min"
        else np.ones(len(rows), np.int64)
    )
    s = rng.integers(0, 2**12, size=len(rows)).astype(np.int64)
    a = lexicographic_assignment(rows, cols, p, s, secondary_sense=sense)
    check_matching(a, rows, cols)
    assert (a.primary, a.secondary) == exact_by_lsa(n, m, rows, cols, p, s, sense)


@pytest.mark.parametrize("offset", [-(2**40), 10**12])
def test_ids_far_from_indices_give_the_same_matching(offset):
    """Rows and columns named by large or negative ids (compacted by sorting, not counting) match as the
    same pairs named by small indices do, pair for pair."""
    rng = np.random.default_rng(7)
    rows, cols = random_pairs(rng, 120, 150, 0.1)
    p = rng.integers(0, 4, size=len(rows)).astype(np.int64)
    s = rng.integers(0, 2**10, size=len(rows)).astype(np.int64)
    a = lexicographic_assignment(rows, cols, p, s, secondary_sense="min")
    b = lexicographic_assignment(rows * 7 + offset, cols * 3 + offset, p, s, secondary_sense="min")
    assert len(a.pair) > 50 and np.array_equal(a.pair, b.pair)
    assert (a.primary, a.secondary) == (b.primary, b.secondary)


@pytest.mark.slow
def test_at_the_limits():
    """2000 riders x 5000 taxis (SD_MAX_RIDERS x SD_MAX_TAXIS), ~40 candidates per rider."""
    rng = np.random.default_rng(2000)
    n, m = 2000, 5000
    rows = np.repeat(np.arange(n), 40)
    cols = rng.integers(0, m, size=len(rows))
    uniq = np.unique(rows * m + cols)
    rows, cols = (uniq // m).astype(np.int64), (uniq % m).astype(np.int64)
    p = rng.integers(1, 2**8, size=len(rows)).astype(np.int64)
    s = rng.integers(0, 2**8, size=len(rows)).astype(np.int64)
    a = lexicographic_assignment(rows, cols, p, s, secondary_sense="min")
    check_matching(a, rows, cols)
    assert (a.primary, a.secondary) == exact_by_lsa(n, m, rows, cols, p, s, "min")


def test_empty_and_sense():
    e = np.zeros(0, dtype=np.int64)
    a = lexicographic_assignment(e, e, e, e, secondary_sense="min")
    assert a.rows.size == 0 and a.primary == 0
    with pytest.raises(ValueError):
        lexicographic_assignment(e, e, e, e, secondary_sense="up")


def test_zero_primary_pairs_are_not_matched_when_minimizing():
    rows = np.array([0, 0, 1])
    cols = np.array([0, 1, 1])
    p = np.array([0, 5, 0])
    s = np.array([1, 1, 1])
    a = lexicographic_assignment(rows, cols, p, s, secondary_sense="min")
    assert list(itertools.starmap(lambda r, c: (int(r), int(c)), zip(a.rows, a.cols, strict=True))) == [
        (0, 1)
    ]
