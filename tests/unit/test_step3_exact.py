"""Step 3 without a reach against the straightforward per-taxi computation.

Without a reach (a network under ``step3_reach_above_s``) every free instrumented taxi is a candidate for
every POI. The straightforward computation grows one full tree per taxi and kappa from the taxi
(``plan_routes(..., fastest_from_targets=False)``, itself checked against the book in ``test_routing.py``);
``plan_routes`` as Step 3 calls it takes whatever shortcuts it takes. Here the instances are the hard case of
those shortcuts: many taxis, few POIs, and every taxi counted in many cells of the first slot (as on a
platform's heavy load late in an interval, where most in-tree routes enter a cell their taxi is counted
in). Everything Step 3 reads must be identical, bit for bit: the kappa, gain, time and length of every
pair, the fastest path's cost and the largest slot any route reaches (it sizes the gain table); Step 3's
assignment reads nothing else (phi and the candidate pairs are derived from them), so it is the same too. On
lattices with equal blocks (ties everywhere) and jittered ones.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from services.citydata import load_city
from services.model import CountsView, IntervalKey, TaxiId
from services.network import astar, dijkstra
from services.network.graph import INF, Costs, road_graph
from services.network.pads import Pads
from services.routing import algorithm1
from services.routing.algorithm1 import Drive, Plans, plan_routes, problem
from services.sensing.gains import counted_csr, gain_table, mark
from tests import reference as ref
from tests.citymaker import T0, make_city

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"
KAPPAS = (0.0, 0.3, 0.6, 0.9)
FIELDS = ("kappa_index", "gain", "time_s", "length_m", "d0_us")


def _lattice(rng: np.random.Generator, n: int, jitter: float):
    """An ``n x n`` lattice of two-way streets 250 m apart in 1 km cells, off the cell edges (jitter 0:
    every block equal)."""
    nodes = {
        r * n + c: (
            110.0 + c * 250.0 + rng.uniform(-jitter, jitter),
            110.0 + r * 250.0 + rng.uniform(-jitter, jitter),
        )
        for r in range(n)
        for c in range(n)
    }
    edges = [(r * n + c, r * n + c + 1) for r in range(n) for c in range(n - 1)]
    edges += [(r * n + c, (r + 1) * n + c) for r in range(n - 1) for c in range(n)]
    return make_city(nodes, edges)


def _same(got: Plans, straight: Plans) -> None:
    for name in FIELDS:
        assert np.array_equal(getattr(got, name), getattr(straight, name)), name
    assert got.max_slot == straight.max_slot


def _heavy_counts(
    rng: np.random.Generator, n_cells: int, k0: int, taxis: list[TaxiId], share: float
) -> CountsView:
    """Counts of 0-2 per cell in two slots, and every taxi counted in about ``share`` of the cells of the
    first slot (and a few of the second)."""
    counts = {IntervalKey(k0 + s): rng.integers(0, 3, n_cells) for s in range(2)}
    visited = {}
    for t in taxis:
        first = rng.choice(n_cells, max(1, int(share * n_cells)), replace=False)
        second = rng.choice(n_cells, 2, replace=False)
        visited[t] = frozenset(
            [(IntervalKey(k0), int(c)) for c in first] + [(IntervalKey(k0 + 1), int(c)) for c in second]
        )
    return CountsView(counts, visited)


def _plans_both(graph, gn, counted, sources: NDArray[np.int64], targets: NDArray[np.int64], now: float):
    pb = problem(gn, counted, sources, targets, KAPPAS, now)
    return plan_routes(graph, pb, 2, Pads(graph)), plan_routes(
        graph, pb, 1, Pads(graph), fastest_from_targets=False
    )


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("jitter", [40.0, 0.0])
def test_step3_without_reach_equals_one_tree_per_taxi_and_kappa(seed: int, jitter: float) -> None:
    """60 taxis, each counted in 5-35 % of the cells, and 2-9 POIs on a 14 x 14 lattice: the plans are the
    straightforward computation's; a few taxis' routes are the book's too."""
    rng = np.random.default_rng(seed)
    city = _lattice(rng, 14, jitter)
    graph = road_graph(city)
    now = T0 + 3600 - 300.0 * (seed % 4)  # some routes run into the next interval
    k0 = city.horizon.interval_of(now)
    taxis = [TaxiId(f"t{i}") for i in range(60)]
    view = _heavy_counts(rng, city.grid.n_cells, k0, taxis, 0.05 + 0.03 * seed)
    gn = gain_table(city, view.counts, k0, 2, now)
    counted = counted_csr(view.visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=True).astype(np.int64)  # taxis may share nodes
    targets = rng.choice(graph.n_nodes, int(rng.integers(2, 10)), replace=False).astype(np.int64)
    got, straight = _plans_both(graph, gn, counted, sources, targets, now)
    _same(got, straight)
    assert (got.kappa_index > 0).any()
    for i in range(0, len(taxis), 20):
        lo, hi = counted.ptr[i], counted.ptr[i + 1]
        zero = set(zip(counted.slot[lo:hi].tolist(), counted.cell[lo:hi].tolist(), strict=True))
        book = ref.algorithm1(graph, gn, zero, int(sources[i]), targets.tolist(), now, KAPPAS)
        for j, (kappa, _edges, g, t, _length) in enumerate(book):
            assert KAPPAS[got.kappa_index[i, j]] == kappa
            assert got.gain[i, j] == pytest.approx(g, rel=1e-12, abs=1e-300)
            assert got.time_s[i, j] == pytest.approx(t, rel=1e-12)


def test_tied_taxis_are_planned_as_the_straightforward_computation_plans_them() -> None:
    """Taxis stacked on the same nodes with the same counted cells have equal phi to every POI: their plans,
    which Step 3's assignment among the tied taxis reads, are the straightforward computation's."""
    rng = np.random.default_rng(99)
    city = _lattice(rng, 12, 0.0)
    graph = road_graph(city)
    now = T0 + 1800.0
    k0 = city.horizon.interval_of(now)
    taxis = [TaxiId(f"t{i}") for i in range(40)]
    base = _heavy_counts(rng, city.grid.n_cells, k0, taxis[:10], 0.2)
    view = CountsView(base.counts, {t: base.visited[taxis[i % 10]] for i, t in enumerate(taxis)})
    counted = counted_csr(view.visited, taxis, k0)
    gn = gain_table(city, view.counts, k0, 2, now)
    spots = rng.choice(graph.n_nodes, 10, replace=False)
    sources = np.array([spots[i % 10] for i in range(len(taxis))], dtype=np.int64)
    targets = rng.choice(graph.n_nodes, 6, replace=False).astype(np.int64)
    got, straight = _plans_both(graph, gn, counted, sources, targets, now)
    _same(got, straight)
    assert np.array_equal(got.phi[:10], got.phi[10:20])  # the ties are there


@pytest.mark.slow
def test_step3_at_the_apis_largest_size_equals_the_straightforward_computation() -> None:
    """The API's largest epoch for Step 3 without a reach: 5,000 free instrumented taxis on Chengdu (under
    an hour across), each counted in a fifth of the cells, and 1,000 open POIs (``SD_MAX_TASKS``); and the
    same taxis with 40 POIs, where the POIs' in-trees serve the taxis."""
    city = load_city(BUNDLES / "chengdu")
    graph = road_graph(city)
    rng = np.random.default_rng(2024)
    now = T0 + 2400.0
    k0 = city.horizon.interval_of(now)
    taxis = [TaxiId(f"t{i}") for i in range(5000)]
    view = _heavy_counts(rng, city.grid.n_cells, k0, taxis, 0.2)
    gn = gain_table(city, view.counts, k0, 2, now)
    counted = counted_csr(view.visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=True).astype(np.int64)
    pois = rng.choice(graph.n_nodes, 1000, replace=False).astype(np.int64)
    for targets in (pois[:40], pois):
        got, straight = _plans_both(graph, gn, counted, sources, targets, now)
        _same(got, straight)


def test_a_re_searched_route_stopped_where_the_in_tree_path_leaves_the_counted_cells_is_the_full_search() -> (
    None
):
    """``astar.guided`` with the in-tree's path cells stops short of the POI, and away from the taxi, in
    many searches, and the route it gives (the path to where it stopped, then the in-tree's path) is the
    route of the search run to the POI, bit for bit."""
    rng = np.random.default_rng(7)
    city = _lattice(rng, 14, 0.0)
    graph = road_graph(city)
    now = T0 + 1200.0
    k0 = city.horizon.interval_of(now)
    taxis = [TaxiId(f"t{i}") for i in range(40)]
    view = _heavy_counts(rng, city.grid.n_cells, k0, taxis, 0.25)
    gn = gain_table(city, view.counts, k0, 2, now)
    counted = counted_csr(view.visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=True).astype(np.int64)
    pb = problem(
        gn, counted, sources, rng.choice(graph.n_nodes, 3, replace=False).astype(np.int64), KAPPAS, now
    )
    kt = algorithm1.kit(graph, KAPPAS)
    base = algorithm1._base_kappa(kt, gn, pb.kappas, True)
    stopped = searched = 0
    with Pads(graph).take() as pad:
        tl = algorithm1.tools(pad, gn)
        sc = tl.sc
        for root in pb.targets.tolist():
            for q in (1, 3):
                costs = Costs(base.edge[q], base.se[q], base.width[q], base.span[q])
                dijkstra.run(kt.rg, kt.ed, costs, root, INF - 1, np.zeros(0, np.int64), tl.wsr)
                astar.path_cells(kt.rg, kt.ed, tl.wsr, sc.cbits, sc.cdone, 10**9 + q, sc.cstack)
                for a, src in enumerate(sources.tolist()):
                    mark(sc.zmask, counted, a, True)
                    mine, lazy = algorithm1._own_metric(kt, sc, gn, q, KAPPAS[q], base.umax)
                    leg = Drive(a, src, root, INF - 1)
                    got = []
                    for clean in (sc.cbits, sc.cbits[:0]):
                        gd = astar.tree_guide(tl.wsr, INF - 1, clean, algorithm1._zbits(counted, a, sc.zbits))
                        got.append(algorithm1._own_route(kt, pb, tl, costs, gd, lazy, mine, leg))
                        if clean.shape[0]:
                            meet = astar.guided(kt.fg, kt.ed, mine, src, root, tl.wsf, gd, lazy)
                            stopped += meet >= 0 and kt.fg.kept[meet] not in (root, src)
                    mark(sc.zmask, counted, a, False)
                    assert got[0] == got[1]
                    searched += 1
    assert stopped > searched // 4
