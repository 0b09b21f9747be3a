"""Compiled kernels against scipy and plain Python."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.csgraph as cg

from services import kernels
from services.model import CountsView, IntervalKey, TaxiId
from services.routing import gain_table, graph_arrays
from services.sensing import timed_cells
from tests import reference as ref
from tests.citymaker import T0, grid_city


@pytest.mark.parametrize("seed", range(10))
def test_dijkstra_matches_scipy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    city = grid_city(7, 300.0)
    ga = graph_arrays(city)
    cost = ga.time_s * rng.uniform(0.2, 1.0, len(ga.time_s))
    src = int(rng.integers(city.network.n_nodes))
    dist, pred, acc = kernels.dijkstra(
        ga.indptr, ga.head, cost, src, np.inf, np.zeros(0, dtype=np.int64), ga.length_m
    )
    expect = cg.dijkstra(city.network.csr(cost), indices=src)
    np.testing.assert_allclose(dist, expect, rtol=1e-12)
    # the tree is a shortest-path tree: every pred edge is tight
    for v in range(city.network.n_nodes):
        if v != src:
            e = pred[v]
            assert dist[ga.tail[e]] + cost[e] == pytest.approx(dist[v], rel=1e-12)
            assert acc[ga.tail[e]] + ga.length_m[e] == pytest.approx(acc[v], rel=1e-12)
    # limit and early stop keep correct distances for what they settle
    lim = float(np.median(expect))
    dl, _, _ = kernels.dijkstra(ga.indptr, ga.head, cost, src, lim, np.zeros(0, dtype=np.int64), ga.length_m)
    ok = np.isfinite(dl)
    np.testing.assert_allclose(dl[ok], expect[ok])
    assert (expect[~ok] > lim).all()


def kernel_gain(city, counts: CountsView, taxi: str, edges: np.ndarray, now: float) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Gain and travel time of a path as the dispatch computes them: the gain table and ``eval_path``."""
    k0 = city.horizon.interval_of(now)
    table = gain_table(city, counts.counts, k0, 3, now)
    gain, gain_q = table.for_taxi(counts.visited.get(TaxiId(taxi)))
    stamp, sid = table.stamps(1)
    ga = graph_arrays(city)
    got, _, t, _, _ = kernels.eval_path(
        edges, now, ga.time_s, *ga.cells, *table.clock, gain, gain_q, stamp, sid
    )
    return float(got), float(t)


@pytest.mark.parametrize("seed", range(10))
def test_path_gain_kernel_equals_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    city = grid_city(6, 370.0)
    now = T0 + 3600 - 60.0 * (seed % 4)  # near an interval boundary: pairs split across intervals
    k0 = city.horizon.interval_of(now)
    n_cells = city.grid.n_cells
    counts = CountsView(
        {IntervalKey(k0): rng.integers(0, 4, n_cells), IntervalKey(k0 + 1): rng.integers(0, 4, n_cells)},
        {TaxiId("a"): frozenset({(IntervalKey(k0), int(c)) for c in rng.choice(n_cells, 3)})},
    )
    g = ref.nx_graph(city)
    a, b = rng.choice(city.network.n_nodes, 2, replace=False)
    nodes, _ = ref.fastest(g, int(a), int(b))
    edges = np.array(ref.path_edges(g, nodes), dtype=np.int64)
    got, t = kernel_gain(city, counts, "a", edges, now)
    assert got == pytest.approx(ref.gain(city, counts, "a", edges, now), rel=1e-12)
    assert t == pytest.approx(sum(city.network.edge_time_s[e] for e in edges))
    # the timed G-route lists each (interval, cell) once, in the order the reference meets them
    expect_pairs = list(dict.fromkeys((k, c) for k, c, _ in ref.crossings(city, edges, now)))
    assert timed_cells(city, edges, now).pairs() == expect_pairs


def test_marginal_gain_by_hand() -> None:
    # 2 x 1 cells: a straight edge from (100, 500) to (1900, 500) crosses cell 0 then cell 1.
    from tests.citymaker import make_city

    city = make_city({0: (100.0, 500.0), 1: (1900.0, 500.0)}, [(0, 1)])
    k = city.horizon.interval_of(T0)
    counts = CountsView({IntervalKey(k): np.array([3, 0])})
    edges = np.array([0], dtype=np.int64)  # 0 -> 1
    # mu = 1/4, s = 1/2: (1/8) * ((4^0.2 - 3^0.2) + (1 - 0))
    expect = (1 / 8) * ((4**0.2 - 3**0.2) + 1.0)
    assert kernel_gain(city, counts, "x", edges, T0)[0] == pytest.approx(expect, rel=1e-14)
    # outside the horizon mu is 0
    assert kernel_gain(city, counts, "x", edges, T0 - 7200)[0] == 0.0
