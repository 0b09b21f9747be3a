"""Invariants the fast paths of the dispatch core rely on: each shortcut gives bit-identical results to the
straightforward computation it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from services import contraction, kernels
from services.model import IntervalKey
from services.routing import gain_table, graph_arrays
from tests.citymaker import T0, make_city


def jittered_city(rng: np.random.Generator, n: int = 8, spacing: float = 430.0):  # type: ignore[no-untyped-def]
    """An ``n x n`` lattice of two-way streets with jittered nodes, so no two paths tie exactly."""
    nodes = {
        r * n + c: (c * spacing + rng.uniform(-60, 60), r * spacing + rng.uniform(-60, 60))
        for r in range(n)
        for c in range(n)
    }
    edges = [(r * n + c, r * n + c + 1) for r in range(n) for c in range(n - 1)]
    edges += [(r * n + c, (r + 1) * n + c) for r in range(n - 1) for c in range(n)]
    return make_city(nodes, edges)


def _table(seed: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    city = jittered_city(rng)
    now = T0 + 3600 - 40.0 * (seed % 5)  # near an interval boundary: paths run into the next interval
    k0 = city.horizon.interval_of(now)
    counts = {IntervalKey(k0 + s): rng.integers(0, 3, city.grid.n_cells) for s in range(2)}
    table = gain_table(city, counts, k0, 2, now)  # 2 slots: some crossings overflow the table
    visited = frozenset((IntervalKey(k0 + int(s)), int(c)) for s, c in rng.integers(0, 2, (4, 2)) * [1, 1])
    gain, gain_q = table.for_taxi(visited)
    return rng, city, now, table, gain, gain_q


@pytest.mark.parametrize("seed", range(12))
def test_eval_tree_equals_eval_targets(seed: int) -> None:
    """Evaluating every target's tree path at once (depth-first over the union of the paths) gives exactly
    what evaluating each path on its own gives: gains, integer gains, times, lengths and the largest slot."""
    rng, city, now, table, gain, gain_q = _table(seed)
    ga = graph_arrays(city)
    n = city.network.n_nodes
    unreached = 0
    for trial in range(6):
        cost = ga.time_s * rng.uniform(0.3, 1.0, len(ga.time_s))
        source = int(rng.integers(n))
        targets = rng.choice(n, size=int(rng.integers(1, n)), replace=False).astype(np.int64)
        if trial % 2:
            targets = np.concatenate([targets, [source], targets[:3]]).astype(np.int64)  # source, repeats
        full, _p, _a = kernels.dijkstra(ga.indptr, ga.head, cost, source, np.inf, np.zeros(0, np.int64), cost)
        limit = np.inf if trial < 3 else float(np.median(full))  # some targets unreached
        _d, pred, _a = kernels.dijkstra(
            ga.indptr, ga.head, cost, source, limit, np.zeros(0, np.int64), ga.time_s
        )
        stamp, first = table.stamps(len(targets))
        expect = kernels.eval_targets(
            pred,
            ga.tail,
            targets,
            now,
            ga.time_s,
            ga.length_m,
            *ga.cells,
            *table.clock,
            gain,
            gain_q,
            stamp,
            first,
        )
        got = kernels.eval_tree(
            pred, ga.tail, source, targets, now, ga.time_s, ga.length_m, *ga.cells, *table.clock, gain, gain_q
        )
        for a, b in zip(got[:4], expect[:4], strict=True):
            assert np.array_equal(a, b)
        assert got[4] == expect[4]
        unreached += int((pred[targets] < 0).sum())
    assert unreached > 0


@pytest.mark.parametrize("seed", range(6))
def test_plan_kappas_on_the_contracted_graph_equals_per_kappa_reference(seed: int) -> None:
    """The fused Algorithm 1 kernel against the step-by-step reference (``plan_routes`` with contraction
    off): chosen kappa, evaluations, the routes read off the trees and the largest slot."""
    from services.model import TaxiId
    from services.routing import plan_routes

    rng, city, now, table, _gain, _gq = _table(seed)
    n = city.network.n_nodes
    targets = rng.choice(n, size=int(rng.integers(1, n)), replace=False).astype(np.int64)
    visited = frozenset({(IntervalKey(table.k0), int(c)) for c in rng.choice(city.grid.n_cells, 2)})
    source = int(rng.integers(n))
    try:
        contraction.ENABLED = False
        ref, ref_ms = plan_routes(city, table, TaxiId("a"), source, visited, targets, now)
    finally:
        contraction.ENABLED = True
    got, got_ms = plan_routes(city, table, TaxiId("a"), source, visited, targets, now)
    assert got_ms == ref_ms
    for name in ("kappa", "gain", "time_s", "length_m"):
        assert np.array_equal(getattr(got, name), getattr(ref, name)), name
    for i in range(len(targets)):
        assert np.array_equal(got.route(i).edges, ref.route(i).edges)


@pytest.mark.parametrize("seed", range(10))
def test_tree_search_gives_the_paths_of_dijkstra_contracted(seed: int) -> None:
    """The pred-only search of Algorithm 1 (costs in super-edge order) reads off the same tree path to every
    target as ``dijkstra_contracted``: interior and kept sources, interior and kept targets, dead ends, chain
    cycles, unreachable targets, a target at the source."""
    from tests.unit.test_contraction import chain_graph, interior_sources

    g = chain_graph(seed)
    c = contraction.contract(g.indptr, g.head)
    rng = np.random.default_rng(seed + 100)
    cost = g.length * rng.uniform(0.2, 1.0, len(g.length))
    for s in interior_sources(c, rng, 4):
        for k in (1, 3, 20, g.n):
            targets = rng.choice(g.n, size=min(k, g.n), replace=False).astype(np.int64)
            if k == 3:
                targets = np.concatenate([targets, [s]]).astype(np.int64)
            _d, expect, _a = kernels.dijkstra_contracted(
                *c.arrays, cost, g.length, s, np.inf, targets, targets
            )
            got = np.full(g.n, -1, dtype=np.int64)
            kernels.tree_search(*c.arrays, cost[c.se_edges], s, targets, got)
            for t in targets.tolist():
                assert (got[t] >= 0) == (expect[t] >= 0)
                assert np.array_equal(
                    kernels.walk_edges(got, g.tail, t), kernels.walk_edges(expect, g.tail, t)
                )
