"""Step 3 without a reach against the straightforward per-taxi computation.

Without a reach (a network under ``step3_reach_above_s``) every free instrumented taxi is a candidate for
every POI. The straightforward computation grows one full tree per taxi and kappa from the taxi, computing
every crossing super-edge's cost as it reaches it (``plan_routes(..., fastest_from_targets=False)`` with no
``Overlay``, itself checked against the book in ``test_routing.py``);
``plan_routes`` as Step 3 calls it takes whatever shortcuts it takes. Here the instances are the hard case of
those shortcuts: many taxis, few POIs, and every taxi counted in many cells of the first slot (as on a
platform's heavy load late in an interval, where most in-tree routes enter a cell their taxi is counted
in). Everything Step 3 reads must be identical, bit for bit: the kappa, gain, time and length of every
pair, the fastest path's cost and the largest slot any route reaches (it sizes the gain table); Step 3's
assignment reads nothing else (phi and the candidate pairs are derived from them), so it is the same too. On
lattices with equal blocks (ties everywhere) and jittered ones, with straight streets or streets bent through
degree-2 nodes (chains, whose interior taxis and POIs the searches reach only through the chains' ends); and
the re-searched routes' early stop on small hand-built cities whose routes end inside a chain.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from services.citydata import load_city
from services.model import CountsView, IntervalKey, TaxiId
from services.network import astar, dijkstra, unfolding
from services.network.graph import INF, Costs, no_lazy, prepare, road_graph
from services.network.heaps import workspace
from services.network.scratch import ScratchPool
from services.routing import algorithm1
from services.routing.algorithm1 import Drive, Plans, plan_routes, problem
from services.sensing.gains import counted_csr, gain_table, mark
from tests import reference as ref
from tests.citymaker import T0, make_city

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"
KAPPAS = (0.0, 0.3, 0.6, 0.9)
FIELDS = ("kappa_index", "gain", "time_s", "length_m", "d0_us")


def _lattice(rng: np.random.Generator, n: int, jitter: float, split: float = 0.0):
    """An ``n x n`` lattice of two-way streets 250 m apart in 1 km cells, off the cell edges (jitter 0:
    every block equal); a share ``split`` of the streets bent through 1-3 nodes of degree 2 each (up to 60 m
    off the straight line), so that the searches run over chains of interior nodes too."""
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
    if split > 0:
        bent = []
        for u, v in edges:
            prev = u
            if rng.random() < split:
                (x0, y0), (x1, y1) = nodes[u], nodes[v]
                m = int(rng.integers(1, 4))
                for i in range(1, m + 1):
                    f = i / (m + 1)
                    w = len(nodes)
                    nodes[w] = (
                        x0 + f * (x1 - x0) + rng.uniform(-60, 60),
                        y0 + f * (y1 - y0) + rng.uniform(-60, 60),
                    )
                    bent.append((prev, w))
                    prev = w
            bent.append((prev, v))
        edges = bent
    return make_city(nodes, edges)


def _on_chains(
    rng: np.random.Generator, graph, targets: NDArray[np.int64], sources: NDArray[np.int64]
) -> None:
    """Put half the taxis on the chains the POIs lie inside (taxi and POI inside one chain, or the taxi
    inside the chain whose end the search toward the POI settles), where they are on a bent lattice."""
    fg = graph.forward
    on = [
        int(v)
        for t in targets.tolist()
        for s in fg.pos_se[t].tolist()
        if s >= 0
        for v in fg.se_node[fg.se_ptr[s] : fg.se_ptr[s + 1]].tolist()
    ]
    if on:
        half = len(sources) // 2
        sources[:half] = rng.choice(on, half)


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
    """Step 3's plans and the straightforward computation's: one tree per taxi and kappa from the taxi,
    every crossing super-edge's cost computed as the search reaches it (no ``algorithm1.Overlay``)."""
    pb = problem(gn, counted, sources, targets, KAPPAS, now)
    got = plan_routes(graph, pb, 2, ScratchPool(graph))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(algorithm1, "OVERLAY_TAXIS", 10**9)
        straight = plan_routes(graph, pb, 1, ScratchPool(graph), fastest_from_targets=False)
    return got, straight


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize(("jitter", "split"), [(40.0, 0.0), (0.0, 0.0), (40.0, 0.5), (0.0, 0.5)])
def test_step3_without_reach_equals_one_tree_per_taxi_and_kappa(
    seed: int, jitter: float, split: float
) -> None:
    """60 taxis, each counted in 5-35 % of the cells, and 2-9 POIs on a 14 x 14 lattice, straight or with
    half its streets bent through interior nodes (half the taxis then inside the POIs' chains): the plans
    are the straightforward computation's; a few taxis' routes are the book's too."""
    rng = np.random.default_rng(seed)
    city = _lattice(rng, 14, jitter, split)
    graph = road_graph(city)
    now = T0 + 3600 - 300.0 * (seed % 4)  # some routes run into the next interval
    k0 = city.horizon.interval_of(now)
    taxis = [TaxiId(f"t{i}") for i in range(60)]
    view = _heavy_counts(rng, city.grid.n_cells, k0, taxis, 0.05 + 0.03 * seed)
    gn = gain_table(city, view.counts, k0, 2, now)
    counted = counted_csr(view.visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=True).astype(np.int64)  # taxis may share nodes
    targets = rng.choice(graph.n_nodes, int(rng.integers(2, 10)), replace=False).astype(np.int64)
    if split > 0:
        _on_chains(rng, graph, targets, sources)
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


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(("jitter", "split"), [(40.0, 0.0), (0.0, 0.0), (40.0, 0.5), (0.0, 0.5)])
def test_taxis_trees_over_the_base_costs_equal_trees_computing_every_cost(
    seed: int, jitter: float, split: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """As many POIs as taxis, so every taxi grows its own trees: read off the epoch's base kappa costs
    (``algorithm1.Overlay``) but on the super-edges entering a cell the taxi is counted in, they are the
    straightforward computation's bit for bit, with taxis counted in 10-60 % of the cells, four of them in
    every cell but one (most likely where the utility peaks: their normalization is their own), and taxis
    sharing nodes."""
    made = []
    overlay_base = algorithm1._overlay_base

    def spy(*args):
        made.append(1)
        return overlay_base(*args)

    monkeypatch.setattr(algorithm1, "_overlay_base", spy)
    rng = np.random.default_rng(100 + seed)
    city = _lattice(rng, 10, jitter, split)
    graph = road_graph(city)
    now = T0 + 3600 - 300.0 * (seed % 4)
    k0 = city.horizon.interval_of(now)
    taxis = [TaxiId(f"t{i}") for i in range(24)]
    cells = city.grid.n_cells
    view = _heavy_counts(rng, cells, k0, taxis, 0.1 * (seed + 1))
    visited = dict(view.visited)
    for t in taxis[:4]:  # counted in every cell but one: most likely where the utility peaks
        skip = int(rng.integers(cells))
        visited[t] = frozenset((IntervalKey(k0), c) for c in range(cells) if c != skip)
    gn = gain_table(city, view.counts, k0, 2, now)
    counted = counted_csr(visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=True).astype(np.int64)
    targets = rng.choice(graph.n_nodes, 24, replace=False).astype(np.int64)
    if split > 0:
        _on_chains(rng, graph, targets, sources)
    got, straight = _plans_both(graph, gn, counted, sources, targets, now)
    assert made and got.in_trees == 0 and got.taxi_searches > 0
    pb = problem(gn, counted, sources, targets, KAPPAS, now)
    net = algorithm1.kappa_graph(graph, KAPPAS)
    base = algorithm1._base_kappa(net, gn, pb.kappas, False)
    with ScratchPool(graph).take() as scratch:
        own = algorithm1._own_normalized(net, pb, base, algorithm1.route_scratch(scratch, gn))
    assert 0 < own.sum() < len(taxis)  # both kinds of taxi are there
    _same(got, straight)
    assert (got.kappa_index > 0).any()


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


@pytest.mark.parametrize("split", [0.0, 0.5])
def test_a_re_searched_route_stopped_where_the_in_tree_path_leaves_the_counted_cells_is_the_full_search(
    split: float,
) -> None:
    """``astar.guided`` with the in-tree's path cells stops short of the POI, and away from the taxi, in
    many searches, and the route it gives (the path to where it stopped, then the in-tree's path) is the
    route of the search run to the POI, bit for bit; on a straight lattice and on a bent one with half the
    taxis inside the POIs' chains."""
    rng = np.random.default_rng(7)
    city = _lattice(rng, 14, 0.0, split)
    graph = road_graph(city)
    now = T0 + 1200.0
    k0 = city.horizon.interval_of(now)
    taxis = [TaxiId(f"t{i}") for i in range(40)]
    view = _heavy_counts(rng, city.grid.n_cells, k0, taxis, 0.25)
    gn = gain_table(city, view.counts, k0, 2, now)
    counted = counted_csr(view.visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=True).astype(np.int64)
    targets = rng.choice(graph.n_nodes, 3, replace=False).astype(np.int64)
    if split > 0:
        _on_chains(rng, graph, targets, sources)
    pb = problem(gn, counted, sources, targets, KAPPAS, now)
    kt = algorithm1.kappa_graph(graph, KAPPAS)
    base = algorithm1._base_kappa(kt, gn, pb.kappas, True)
    stopped = searched = 0
    stamp = 10**9  # a stamp new for each in-tree, above any the scratch has used
    written = 0
    with ScratchPool(graph).take() as scratch:
        sc = algorithm1.route_scratch(scratch, gn)
        for root in pb.targets.tolist():
            for q in (1, 3):
                costs = Costs(base.edge[q], base.se[q], base.width[q], base.span[q])
                dijkstra.run(kt.rg, kt.ed, costs, root, INF - 1, np.zeros(0, np.int64), sc.reverse)
                stamp += 1
                for a, src in enumerate(sources.tolist()):
                    mark(sc.zmask, counted, a, True)
                    mine, lazy = algorithm1._own_metric(kt, sc, gn, q, KAPPAS[q], base.umax)
                    leg = Drive(a, src, root, INF - 1)
                    got = []
                    for clean in (sc.cbits, sc.cbits[:0]):
                        zbits = algorithm1._zbits(counted, a, sc.zbits)
                        cells = (clean, sc.cdone, sc.cstack)
                        gd = astar.tree_guide(kt.rg, sc.reverse, INF - 1, cells, stamp, zbits)
                        got.append(algorithm1._own_route(kt, pb, sc, costs, gd, lazy, mine, leg))
                        if clean.shape[0]:
                            meet = astar.guided(kt.fg, kt.ed, mine, src, root, sc.forward, gd, lazy)
                            stopped += meet >= 0 and kt.fg.kept[meet] not in (root, src)
                    mark(sc.zmask, counted, a, False)
                    assert got[0] == got[1]
                    searched += 1
                written += _check_path_cells(kt, costs, sc, stamp)
    assert stopped > searched // 4
    assert written > 0


def _check_path_cells(
    kt: algorithm1.KappaGraph, costs: Costs, sc: algorithm1.RouteScratch, stamp: int
) -> int:
    """Every in-tree node whose path cells the guided searches had written (``cdone == stamp``) holds the
    cells its in-tree path (unfolded edge by edge) enters, each edge's cells but its first; returns how many
    there were."""
    written = np.flatnonzero(sc.cdone == stamp)
    root = sc.reverse.info[0]
    for k in written.tolist():
        x = int(kt.rg.kept[k])
        assert unfolding.unfold(kt.rg, kt.ed, costs, INF - 1, x, sc.reverse)
        want = np.zeros(astar.CLEAN_WORDS, np.uint64)
        for e in unfolding.walk(kt.ed, sc.reverse.pred, x, root).tolist():
            for c in kt.ed.ec_cell[kt.ed.ec_ptr[e] + 1 : kt.ed.ec_ptr[e + 1]].tolist():
                astar.cell_bit(want, c)
        assert sc.cbits[k].tolist() == want.tolist(), x
    return int(written.shape[0])


def _route(g, mine: Costs, base_rev: Costs, wsf, wsr, gd: astar.Guide, src: int, dst: int) -> list[int]:
    """``_own_route``'s route: the guided search's path, or the path to where it stopped, then the
    in-tree's."""
    ed = g.edges
    meet = astar.guided(g.forward, ed, mine, src, dst, wsf, gd, no_lazy())
    if meet < 0:
        assert unfolding.unfold(g.forward, ed, mine, INF, dst, wsf)
        return [int(e) for e in unfolding.path_to(ed, 1, wsf.pred, src, dst)]
    x = int(g.forward.kept[meet])
    unfolding.unfold(g.forward, ed, mine, INF, x, wsf)
    head = [int(e) for e in unfolding.path_to(ed, 1, wsf.pred, src, x)]
    unfolding.unfold(g.reverse, ed, base_rev, INF - 1, x, wsr)
    return head + [int(e) for e in unfolding.walk(ed, wsr.pred, x, dst)]


def _every_pair(
    order: str,
    xy: Mapping[str, tuple[float, float]],
    base_ms: dict[str, int],
    mine_ms: dict[str, int],
    kept: str,
    both_ways: bool = True,
) -> dict[tuple[str, str], tuple[list[tuple[str, str]], int]]:
    """On the city of nodes ``xy`` (one letter each, numbered in ``order``) and streets ``base_ms`` (role
    pair: the in-tree's cost in ms, either way on two-way streets), where the taxi's own costs are the base's
    but ``mine_ms`` on the edges entering the cell above (its counted cell): every pair's route of the
    guided search with the early stop (``_own_route``'s) is the full search's and the plain search's, bit
    for bit. Returns each pair's route (as role pairs) and its cost under the taxi's costs (us)."""
    node = {r: i for i, r in enumerate(order)}
    city = make_city(
        {node[r]: p for r, p in xy.items()}, [(node[p[0]], node[p[1]]) for p in base_ms], both_ways=both_ways
    )
    g = road_graph(city)
    ed = g.edges
    assert sorted(g.forward.kept.tolist()) == sorted(node[r] for r in kept)
    edge = {(order[a], order[b]): e for e, (a, b) in enumerate(zip(ed.tail, ed.head, strict=True))}
    base = np.zeros(g.n_edges, dtype=np.int64)
    for (a, b), e in edge.items():
        base[e] = base_ms.get(a + b, base_ms.get(b + a, 0)) * 1000
    mine = base.copy()
    zbits = np.zeros(astar.CLEAN_WORDS, dtype=np.uint64)
    for pair, ms in mine_ms.items():
        a, b = pair[0], pair[1]
        if (a, b) in edge:
            e = edge[a, b]
            mine[e] = ms * 1000
            for c in ed.ec_cell[ed.ec_ptr[e] + 1 : ed.ec_ptr[e + 1]].tolist():
                astar.cell_bit(zbits, c)
    for e in range(g.n_edges):  # the taxi's costs differ from the base's exactly on the counted cell's edges
        entered = ed.ec_cell[ed.ec_ptr[e] + 1 : ed.ec_ptr[e + 1]].tolist()
        assert base[e] > 0
        assert (mine[e] != base[e]) == any(int(zbits[c // 64]) >> (c % 64) & 1 for c in entered)
    base_rev, mine_fwd = prepare(g.reverse, base), prepare(g.forward, mine)
    wsf, wsr = workspace(g), workspace(g, reverse=True)
    k = g.forward.kept.shape[0]
    clean = np.zeros((k, astar.CLEAN_WORDS), dtype=np.uint64)
    stopped = 0
    routes = {}
    for dst in range(g.n_nodes):
        dijkstra.run(g.reverse, ed, base_rev, dst, INF - 1, np.zeros(0, np.int64), wsr)
        done, stack = np.zeros(k, np.int64), np.zeros(k, np.int64)
        for src in range(g.n_nodes):
            dijkstra.run(g.forward, ed, mine_fwd, src, INF - 1, np.array([dst]), wsf)
            if not unfolding.unfold(g.forward, ed, mine_fwd, INF, dst, wsf):
                continue  # a spur's end, on one-way streets
            plain = unfolding.path_to(ed, 1, wsf.pred, src, dst).tolist()
            full_gd = astar.tree_guide(g.reverse, wsr, INF - 1, (clean[:0], done, stack), dst + 1, zbits)
            full = _route(g, mine_fwd, base_rev, wsf, wsr, full_gd, src, dst)
            assert full == plain
            gd = astar.tree_guide(g.reverse, wsr, INF - 1, (clean, done, stack), dst + 1, zbits)
            stopped += astar.guided(g.forward, ed, mine_fwd, src, dst, wsf, gd, no_lazy()) >= 0
            assert _route(g, mine_fwd, base_rev, wsf, wsr, gd, src, dst) == full, (order[src], order[dst])
            route = [(order[ed.tail[e]], order[ed.head[e]]) for e in full]
            routes[order[src], order[dst]] = route, int(mine[full].sum())
    assert stopped > 0
    return routes


# A chain T - s - d - t - H whose edge s -> d (and t -> d, two-way) enters the cell above (the taxi's counted
# cell; every other edge stays in the cell below), a bypass H - q - T (q interior too) and a spur at T and
# at H, so that T and H are kept.
_CHAIN_XY = {"T": (100, 500), "s": (300, 500), "d": (500, 1500), "t": (700, 500), "H": (900, 500)}
_CHAIN_XY |= {"q": (500, 100), "u": (100, 100), "w": (900, 100)}
_CHAIN_BASE = {"Ts": 20, "sd": 1, "dt": 1, "tH": 2, "Hq": 5, "qT": 5, "Tu": 5, "Hw": 5}
_CHAIN_MINE = {"sd": 29, "td": 29}


@pytest.mark.parametrize("both_ways", [True, False])
@pytest.mark.parametrize("order", ["TsdtHquw", "wuqHtdsT"])
def test_a_re_searched_route_between_two_nodes_of_one_chain_is_the_full_search(
    order: str, both_ways: bool
) -> None:
    """Taxi ``s`` and POI ``t`` inside one two-way chain, a counted cell between them, and a bypass: the
    path along the chain (30 ms under the taxi's costs) passes no kept node, so it is never queued; T
    settles with a key (20 + 12 ms) below H's (30 + 2 + 2) and its in-tree path (the bypass, 10 + 2 ms,
    under the in-tree's 20 + 2 along the chain) enters no counted cell, but stopping there would give
    s -> T -> q -> H -> t (32 ms). The guided search with the early stop gives the full search's route and
    the plain search's, bit for bit, for that pair and every other (the POI before the taxi on the chain,
    the POI at an end of it, either node kept), on the two-way chain and on a one-way one (one-way loop
    T -> H -> q -> T); ``order`` numbers the nodes both ways, so each direction of the chain is the first
    super-edge in turn."""
    routes = _every_pair(order, _CHAIN_XY, _CHAIN_BASE, _CHAIN_MINE, "THuw", both_ways)
    assert routes["s", "t"] == ([("s", "d"), ("d", "t")], 30_000)


# POI t inside the chain A - d - t - B, whose edge A -> d (and t -> d) enters the cell above (the taxi's
# counted cell; every other edge stays in the cell below); the taxi at kept X, joined to A and, dearer, to
# k, which is next to B; a spur at X, A, B and k, so that they are kept.
_END_XY = {"X": (100, 500), "A": (300, 500), "d": (400, 1500), "t": (500, 500), "B": (700, 500)}
_END_XY |= {"k": (400, 100), "u": (100, 800), "v": (300, 800), "w": (700, 800), "z": (400, 300)}
_END_BASE = {"XA": 1, "Ad": 1, "dt": 1, "tB": 10, "Xk": 12, "kB": 1, "Xu": 5, "Av": 5, "Bw": 5, "kz": 5}
_END_MINE = {"Ad": 5, "td": 5}


@pytest.mark.parametrize("order", ["XAdtBkuvwz", "zwvukBtdAX"])
def test_a_re_searched_route_through_a_settled_end_of_the_pois_chain_is_the_full_search(order: str) -> None:
    """Taxi X, POI t inside a chain: the search settles the chain's end A first (key 1 + 2 ms), and the path
    on from A to t (7 ms under the taxi's costs) is never queued; then k, with a key of 12 + 11 ms and an
    in-tree path k -> B -> t that enters no counted cell, before B (whose label comes through k); stopping
    at k would give X -> k -> B -> t (23 ms). The guided search with the early stop gives the full search's
    route and the plain search's, bit for bit, for that pair and every other."""
    routes = _every_pair(order, _END_XY, _END_BASE, _END_MINE, "XABkuvwz")
    assert routes["X", "t"] == ([("X", "A"), ("A", "d"), ("d", "t")], 7_000)
