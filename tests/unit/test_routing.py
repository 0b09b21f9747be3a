"""Algorithm 1, Algorithm 2 and the shortcuts of Step 3 against straightforward computations.

References (``tests/reference.py``) are written in Python from docs/METHOD.md: one canonical Dijkstra per
(taxi, kappa), paths evaluated by the book. The compiled paths must choose the same kappa and the same
edges, with gains and times equal to rounding; and every shortcut must be *bit-identical* to the compiled
computation it replaces: fastest paths from one in-tree per POI instead of one tree per taxi, the
tree-wide evaluation instead of one path at a time, a route found again after the assignment instead of
kept, the re-plans of Algorithm 2 in batches on threads, and a whole epoch on one thread or several.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from services.citydata import load_city
from services.dispatch import decide
from services.epoch import Epoch
from services.kernel.parallel import parallel_map
from services.model import CountsView, IntervalKey, Rider, RiderId, Snapshot, Task, TaskId, Taxi, TaxiId
from services.network import heaps, point_to_point, unfolding
from services.network.graph import INF, kappa_cost, prepare, road_graph
from services.network.scratch import ScratchPool
from services.routing import algorithm1
from services.routing.algorithm1 import Drive, plan_one, plan_routes, problem, route_pair
from services.routing.algorithm2 import improve_routes, joint_utility, route_pairs
from services.sensing.gains import (
    TreeOut,
    counted_csr,
    eval_path,
    eval_tree,
    gain_table,
    path_facts,
    timed_pairs,
    tree_scratch,
)
from services.sensing.sensing import timed_cells
from tests import reference as ref
from tests.citymaker import T0, make_city

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"
KAPPAS = (0.0, 0.3, 0.6, 0.9)


def lattice(rng: np.random.Generator, n: int = 8, spacing: float = 430.0, jitter: float = 60.0):
    """An ``n x n`` lattice of two-way streets; with ``jitter`` 0 every street block is equal (ties)."""
    nodes = {
        r * n + c: (c * spacing + rng.uniform(-jitter, jitter), r * spacing + rng.uniform(-jitter, jitter))
        for r in range(n)
        for c in range(n)
    }
    edges = [(r * n + c, r * n + c + 1) for r in range(n) for c in range(n - 1)]
    edges += [(r * n + c, (r + 1) * n + c) for r in range(n - 1) for c in range(n)]
    return make_city(nodes, edges)


def instance(seed: int, jitter: float = 60.0):
    """A lattice city, counts of the epoch's interval and the next, and a few taxis counted in cells."""
    rng = np.random.default_rng(seed)
    city = lattice(rng, jitter=jitter)
    now = T0 + 3600 - 40.0 * (seed % 5)  # near an interval boundary: paths run into the next interval
    k0 = city.horizon.interval_of(now)
    counts = {IntervalKey(k0 + s): rng.integers(0, 3, city.grid.n_cells) for s in range(2)}
    taxis = [TaxiId(f"t{i}") for i in range(7)]
    visited = {
        t: frozenset(
            (IntervalKey(k0 + int(s)), int(c))
            for s, c in zip(rng.integers(0, 2, 4), rng.integers(0, city.grid.n_cells, 4), strict=True)
        )
        for t in taxis[::2]
    }
    return rng, city, now, k0, CountsView(counts, visited), taxis


def zeroed(counted, i: int) -> set[tuple[int, int]]:
    lo, hi = counted.ptr[i], counted.ptr[i + 1]
    return set(zip(counted.slot[lo:hi].tolist(), counted.cell[lo:hi].tolist(), strict=True))


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("jitter", [60.0, 0.0])
@pytest.mark.parametrize(("overlay_taxis", "landmark_targets"), [(1, 0), (10**9, 0), (1, 3), (10**9, 3)])
def test_algorithm1_against_the_book(
    seed: int, jitter: float, overlay_taxis: int, landmark_targets: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """plan_routes (compiled trees, tree-wide evaluation, fastest paths from the POIs or from the taxis, the
    taxis' trees reading the base kappa costs or computing every cost as they go, or a taxi's few POIs
    searched one by one) equals one canonical Dijkstra per taxi and kappa with every path evaluated by the
    book."""
    monkeypatch.setattr(algorithm1, "OVERLAY_TAXIS", overlay_taxis)
    monkeypatch.setattr(algorithm1, "LANDMARK_TARGETS", landmark_targets)
    rng, city, now, k0, counts, taxis = instance(seed, jitter)
    graph = road_graph(city)
    gn = gain_table(city, counts.counts, k0, 2, now)  # 2 slots: some crossings overflow the table
    counted = counted_csr(counts.visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=False).astype(np.int64)
    targets = rng.choice(graph.n_nodes, 3, replace=False).astype(np.int64)  # fewer than half: POI trees
    plans = {
        how: plan_routes(
            graph,
            problem(gn, counted, sources, targets, KAPPAS, now),
            1,
            ScratchPool(graph),
            fastest_from_targets=how,
        )
        for how in (True, False)
    }
    for name in ("kappa_index", "gain", "time_s", "length_m"):
        assert np.array_equal(getattr(plans[True], name), getattr(plans[False], name)), name
    p = plan_routes(
        graph, problem(gn, counted, sources, targets, KAPPAS, now), 2, ScratchPool(graph)
    )  # chooses itself
    assert np.array_equal(p.gain, plans[True].gain)
    for i, src in enumerate(sources.tolist()):
        book = ref.algorithm1(graph, gn, zeroed(counted, i), src, targets.tolist(), now, KAPPAS)
        for j, (kappa, edges, g, t, length) in enumerate(book):
            assert KAPPAS[p.kappa_index[i, j]] == kappa
            assert p.gain[i, j] == pytest.approx(g, rel=1e-12, abs=1e-300)
            assert p.time_s[i, j] == pytest.approx(t, rel=1e-12)
            assert p.length_m[i, j] == pytest.approx(length, rel=1e-12)
            with ScratchPool(graph).take() as scratch:
                drive = Drive(i, src, int(targets[j]), int(p.d0_us[i, j]))
                route = route_pair(graph, gn, counted, drive, KAPPAS, KAPPAS.index(kappa), scratch)
                fastest = route_pair(graph, gn, counted, drive, KAPPAS, 0, scratch)
            assert route.tolist() == edges
            assert fastest.tolist() == ref.tree_path(
                graph, ref.canonical_tree(graph, graph.edges.time_us, src)[1], src, int(targets[j])
            )


@pytest.mark.parametrize("per_tree", [8, 0])
def test_in_trees_serve_every_kappa_and_taxis_search_again_where_their_counted_cells_lie(
    per_tree: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """From the POIs' in-trees, a taxi is searched again (goal-directed) only for a (kappa, POI) whose
    in-tree route enters a cell it is counted in: over these instances that happens, most routes come
    from the in-trees, and the routes equal one tree per taxi and kappa bit for bit (the check above, here
    on many taxis and cells). With ``GUIDED_PER_TREE`` 0 every taxi with a fastest route entering its
    counted cells grows its own kappa > 0 trees instead: the same routes again."""
    monkeypatch.setattr(algorithm1, "GUIDED_PER_TREE", per_tree)
    own, guided, forward, trees = 0, 0, 0, 0
    for seed in range(6):
        rng, city, now, k0, _counts, _ = instance(seed)
        graph = road_graph(city)
        taxis = [TaxiId(f"t{i}") for i in range(24)]
        cells = city.grid.n_cells
        visited = {
            t: frozenset((IntervalKey(k0), int(c)) for c in rng.integers(0, cells, int(rng.integers(1, 4))))
            for t in taxis[::2]
        }
        counts = CountsView({IntervalKey(k0): rng.integers(0, 3, cells)}, visited)
        gn = gain_table(city, counts.counts, k0, 2, now)
        counted = counted_csr(counts.visited, taxis, k0)
        sources = rng.choice(graph.n_nodes, len(taxis), replace=False).astype(np.int64)
        targets = rng.choice(graph.n_nodes, 5, replace=False).astype(np.int64)
        got = {
            how: plan_routes(
                graph,
                problem(gn, counted, sources, targets, KAPPAS, now),
                2,
                ScratchPool(graph),
                fastest_from_targets=how,
            )
            for how in (True, False)
        }
        for name in ("kappa_index", "gain", "time_s", "length_m"):
            assert np.array_equal(getattr(got[True], name), getattr(got[False], name)), name
        assert got[True].max_slot == got[False].max_slot
        own += got[True].taxi_searches
        guided += got[True].guided_searches
        forward += got[False].taxi_searches
        trees += got[True].in_trees
        assert got[False].in_trees == got[False].guided_searches == 0
    assert trees == 6 * 5 * len(KAPPAS) and forward == 6 * 24 * len(KAPPAS)
    if per_tree:
        assert 0 < guided < 6 * 24 * 5 * (len(KAPPAS) - 1) // 2
        assert own < forward // 10
    else:
        assert guided < own < forward


def test_when_most_taxis_search_on_their_own_no_kappa_in_trees_are_grown(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every taxi counted in several cells and ``GUIDED_PER_TREE`` 0: nearly every taxi's fastest route
    enters its counted cells, so it grows its own kappa > 0 trees. Once fewer than twice as many taxis as
    POIs would still read the kappa > 0 in-trees, none are grown and every taxi searches those kappas
    itself (the rule that chooses the kappa = 0 in-trees): only the kappa = 0 in-trees, no goal-directed
    search, and the same routes as one tree per taxi and kappa."""
    monkeypatch.setattr(algorithm1, "GUIDED_PER_TREE", 0)
    skipped = 0
    for seed in range(4):
        rng, city, now, k0, _counts, _ = instance(seed)
        graph = road_graph(city)
        taxis = [TaxiId(f"t{i}") for i in range(24)]
        cells = city.grid.n_cells
        visited = {t: frozenset((IntervalKey(k0), int(c)) for c in rng.integers(0, cells, 6)) for t in taxis}
        counts = CountsView({IntervalKey(k0): rng.integers(0, 3, cells)}, visited)
        gn = gain_table(city, counts.counts, k0, 2, now)
        counted = counted_csr(counts.visited, taxis, k0)
        sources = rng.choice(graph.n_nodes, len(taxis), replace=False).astype(np.int64)
        targets = rng.choice(graph.n_nodes, 5, replace=False).astype(np.int64)
        got = {
            how: plan_routes(
                graph,
                problem(gn, counted, sources, targets, KAPPAS, now),
                2,
                ScratchPool(graph),
                fastest_from_targets=how,
            )
            for how in (True, False)
        }
        for name in ("kappa_index", "gain", "time_s", "length_m"):
            assert np.array_equal(getattr(got[True], name), getattr(got[False], name)), name
        if got[True].in_trees == len(targets):  # kappa = 0 only
            skipped += 1
            assert got[True].guided_searches == 0
            assert got[True].taxi_searches == len(taxis) * (len(KAPPAS) - 1)
        else:
            assert got[True].in_trees == len(targets) * len(KAPPAS)
    assert skipped >= 2


def test_a_taxi_counted_where_utility_peaks_gets_its_own_normalization() -> None:
    """Every cell but one heavily counted: the edges entering that cell carry the largest utility. A taxi
    counted there has a lower largest utility, so its costs are not the base's raised where it is counted:
    it grows its own trees under its own normalization, and the routes are the book's."""
    rng = np.random.default_rng(3)
    city = lattice(rng)
    now = T0 + 900.0
    k0 = city.horizon.interval_of(now)
    lam = np.full(city.grid.n_cells, 40, dtype=np.int64)
    fresh = int(city.grid.n_cells // 2)
    lam[fresh] = 0
    taxis = [TaxiId(f"t{i}") for i in range(6)]
    counts = CountsView(
        {IntervalKey(k0): lam},
        {t: frozenset({(IntervalKey(k0), fresh), (IntervalKey(k0), fresh - 1)}) for t in taxis[1::2]},
    )
    graph = road_graph(city)
    gn = gain_table(city, counts.counts, k0, 2, now)
    counted = counted_csr(counts.visited, taxis, k0)
    sources = rng.choice(graph.n_nodes, len(taxis), replace=False).astype(np.int64)
    targets = rng.choice(graph.n_nodes, 4, replace=False).astype(np.int64)
    p = plan_routes(graph, problem(gn, counted, sources, targets, KAPPAS, now), 1, ScratchPool(graph))
    for i, src in enumerate(sources.tolist()):
        book = ref.algorithm1(graph, gn, zeroed(counted, i), src, targets.tolist(), now, KAPPAS)
        for j, (kappa, _edges, g, t, _length) in enumerate(book):
            assert KAPPAS[p.kappa_index[i, j]] == kappa
            assert p.gain[i, j] == pytest.approx(g, rel=1e-12, abs=1e-300)
            assert p.time_s[i, j] == pytest.approx(t, rel=1e-12)
    assert len({KAPPAS[k] for k in p.kappa_index.ravel()}) > 1


def guided_cases(name: str):
    """A network, its gains and taxis counted in cells along their fastest paths and at random, with pairs
    to route: the tied lattice (every street block equal), or a bundled city (interior ends included)."""
    if name == "lattice":
        rng, city, now, k0, counts, taxis = instance(3, jitter=0.0)
    else:
        rng = np.random.default_rng(11)
        city = load_city(BUNDLES / name)
        hz = city.horizon  # half an hour into a day's first interval of the horizon, where cells gain
        now = hz.interval_start_s(IntervalKey(19_877 * hz.per_day)) + 1800.0
        k0 = city.horizon.interval_of(now)
        counts = CountsView(
            {IntervalKey(k0 + s): rng.integers(0, 3, city.grid.n_cells) for s in range(2)}, {}
        )
        taxis = [TaxiId(f"t{i}") for i in range(6)]
    graph = road_graph(city)
    pairs = rng.choice(graph.n_nodes, (len(taxis), 6, 2))
    interior = np.flatnonzero(graph.forward.kept_of < 0)
    if interior.size:
        pairs[:, :2, 0] = rng.choice(interior, (len(taxis), 2))
        pairs[:, 1:3, 1] = rng.choice(interior, (len(taxis), 2))
    with ScratchPool(graph).take() as scratch:
        cells = [  # each taxi counted in the cells its first fastest path enters and a few others
            {
                int(c)
                for c in timed_cells(
                    city, point_to_point.fastest_path(graph, scratch.forward, *p[0]), now
                ).cells
            }
            | set(rng.integers(0, city.grid.n_cells, 3).tolist())
            for p in pairs.tolist()
        ]
    visited = {t: frozenset((IntervalKey(k0), c) for c in cs) for t, cs in zip(taxis, cells, strict=True)}
    counts = CountsView(dict(counts.counts), {**counts.visited, **visited})
    return city, graph, now, k0, counts, taxis, pairs


@pytest.mark.parametrize("name", ["lattice", "chengdu", "manhattan"])
def test_searches_between_two_nodes_guided_by_landmarks_find_the_plain_paths(name: str) -> None:
    """The routes found again after Step 3's assignment (``route_pair``) and Algorithm 2's re-plans
    (``plan_one``) search goal-directed: the fastest path by the landmarks' travel-time bounds, a kappa
    route by the same landmarks' bounds under the floor metric (every edge that enters a cell discounted
    fully at the family's largest kappa). The floor is nowhere above any taxi's kappa metric, and every
    path is the one the plain search finds (the graph without landmark tables), for every taxi (its own
    cells zeroed), kappa and pair."""
    city, graph, now, k0, counts, taxis, pairs = guided_cases(name)
    gn = gain_table(city, counts.counts, k0, 3, now)
    counted = counted_csr(counts.visited, taxis, k0)
    kt = algorithm1.kappa_graph(graph, KAPPAS)
    none = np.zeros((0, 0), dtype=np.int64)
    plain = kt._replace(time_lm=none, floor_lm=none)
    floor = algorithm1.floor_metric(graph.edges, max(KAPPAS))
    ed = graph.edges
    crossing = np.flatnonzero(np.diff(ed.ec_ptr) > 1)
    assert (floor[np.diff(ed.ec_ptr) <= 1] == ed.time_us[np.diff(ed.ec_ptr) <= 1]).all()
    with ScratchPool(graph).take() as thread_scratch:
        scratch = algorithm1.route_scratch(thread_scratch, gn)
        for i in range(len(taxis)):
            zmask = np.zeros(gn.term.shape[1], dtype=np.bool_)
            zmask[[c for s, c in zeroed(counted, i) if s == 0]] = True
            u = np.array(
                [
                    gn.term[0, ed.ec_cell[ed.ec_ptr[e] + 1 : ed.ec_ptr[e + 1]]][
                        ~zmask[ed.ec_cell[ed.ec_ptr[e] + 1 : ed.ec_ptr[e + 1]]]
                    ].sum()
                    for e in crossing
                ]
            )
            umax = u.max()
            assert umax > 0  # the taxi's kappa metrics are its own, not the travel time
            for q, kappa in enumerate(KAPPAS):
                own = [kappa_cost(ed.time_s[e], x, umax, kappa) for e, x in zip(crossing, u, strict=True)]
                assert (floor[crossing] <= np.array(own)).all()
                for a, b in pairs[i].tolist():
                    drive = Drive(i, a, b, int(INF) - 1)
                    args = (scratch, gn, counted, drive, q, kappa)
                    assert (
                        algorithm1._kappa_path(kt, *args).tolist()
                        == algorithm1._kappa_path(plain, *args).tolist()
                    )


@pytest.mark.parametrize("seed", range(6))
def test_plan_one_equals_plan_routes_for_one_target(seed: int) -> None:
    rng, city, now, k0, counts, taxis = instance(seed + 40)
    graph = road_graph(city)
    gn = gain_table(city, counts.counts, k0, 3, now)
    counted = counted_csr(counts.visited, taxis, k0)
    pool = ScratchPool(graph)
    for i in range(len(taxis)):
        src, tgt = (int(x) for x in rng.choice(graph.n_nodes, 2, replace=False))
        plans = plan_routes(
            graph, problem(gn, counted, np.array([src] * len(taxis)), np.array([tgt]), KAPPAS, now), 1, pool
        )
        with pool.take() as scratch:
            drive = Drive(i, src, tgt, int(plans.d0_us[i, 0]))
            fastest = route_pair(graph, gn, counted, drive, KAPPAS, 0, scratch)
            route = plan_one(graph, gn, counted, drive, fastest, KAPPAS, now, scratch)
        assert route.kappa == KAPPAS[plans.kappa_index[i, 0]]
        assert (route.gain, route.time_s, route.length_m) == (
            plans.gain[i, 0],
            plans.time_s[i, 0],
            plans.length_m[i, 0],
        )


@pytest.mark.parametrize("seed", range(10))
def test_eval_tree_equals_eval_path(seed: int) -> None:
    """The depth-first evaluation over a tree is bit-identical to evaluating each path alone (repeated
    targets, the source as a target, crossings beyond the table included)."""
    rng, city, now, k0, counts, taxis = instance(seed + 80)
    graph = road_graph(city)
    ed = graph.edges
    gn = gain_table(city, counts.counts, k0, 2, now)
    zmask = np.zeros(gn.term.shape, dtype=bool)
    zmask[0, rng.integers(0, city.grid.n_cells, 3)] = True
    ws = heaps.workspace(graph)
    src = int(rng.integers(graph.n_nodes))
    targets = np.concatenate([rng.integers(0, graph.n_nodes, 12), [src, src]]).astype(np.int64)
    cost = np.maximum(1, (ed.time_us * rng.uniform(0.2, 1.0, graph.n_edges)).astype(np.int64))
    costs = prepare(graph.forward, cost)
    out = np.zeros(len(targets), dtype=np.int64)
    unfolding.tree(graph.forward, ed, costs, src, int(INF), targets, targets, ws, out)
    g, t, length = np.zeros(len(targets)), np.zeros(len(targets)), np.zeros(len(targets))
    ts = tree_scratch(graph.n_nodes, gn.term.shape)
    top = eval_tree(ed, gn, zmask, ws.pred, src, targets, now, ts, TreeOut(g, t, length))
    stamp = np.zeros(gn.term.shape, dtype=np.int64)
    tops = []
    for i, v in enumerate(targets.tolist()):
        edges = unfolding.path_to(ed, 1, ws.pred, src, v)
        gi, _gq, ti, li, ms = eval_path(ed, gn, zmask, stamp, i + 1, edges, now)
        assert (g[i], t[i], length[i]) == (gi, ti, li)
        tops.append(ms)
    assert top == max(tops)
    # the scratch is left as it was found, so the next call on it is the same
    again = np.zeros(len(targets)), np.zeros(len(targets)), np.zeros(len(targets))
    eval_tree(ed, gn, zmask, ws.pred, src, targets, now, ts, TreeOut(*again))
    assert np.array_equal(again[0], g) and np.array_equal(again[1], t)


def book_algorithm2(city, graph, counts, taxis, counted, routes, depart_s, k0, n_slots):
    """Algorithm 2 as docs/METHOD.md section 5 says it, one re-plan after another, each re-plan running
    Algorithm 1 by the book against the counts plus the other routes' planned visits."""
    visited = [counts.visited.get(t, frozenset()) for t in taxis]
    pairs = [
        route_pairs(city, np.array(r[1], dtype=np.int64), v, depart_s)
        for r, v in zip(routes, visited, strict=True)
    ]
    total: Counter[tuple[int, int]] = Counter()
    for ps in pairs:
        total.update(ps)
    history = [joint_utility(city, counts.counts, total)]
    passes, accepted = 0, 0
    planned_at = [-1] * len(routes)
    for _ in range(city.params.max_iter):
        passes += 1
        changed = False
        for i, (src, edges, tgt) in enumerate(routes):
            if planned_at[i] == accepted:
                continue
            planned_at[i] = accepted
            others = total.copy()
            others.subtract(pairs[i])
            extra = np.zeros((n_slots, city.grid.n_cells), dtype=np.int64)
            for (k, c), n in others.items():
                if 0 <= k - k0 < n_slots:
                    extra[k - k0, c] += n
            gn = gain_table(city, counts.counts, k0, n_slots, depart_s, extra_counts=extra)
            ((_kappa, cand, _g, _t, _l),) = ref.algorithm1(
                graph, gn, zeroed(counted, i), src, [tgt], depart_s, KAPPAS
            )
            if cand == edges:
                continue
            cand_pairs = route_pairs(city, np.array(cand, dtype=np.int64), visited[i], depart_s)
            trial = others.copy()
            trial.update(cand_pairs)
            u_new = joint_utility(city, counts.counts, trial)
            if u_new > history[-1] * (1 + 1e-12) + 1e-300:
                routes[i] = (src, cand, tgt)
                pairs[i] = cand_pairs
                total = trial
                history.append(u_new)
                accepted += 1
                planned_at[i] = accepted
                changed = True
        if not changed:
            break
    return routes, history, passes


@pytest.mark.parametrize("workers", [1, 3])
def test_algorithm2_against_the_book(workers: int) -> None:
    """improve_routes (the fastest path kept from Step 3, the others' visits as a dense count, batches of
    re-plans on threads) makes the same replacements, routes and utility history as the book; on these
    instances it does replace routes, so the acceptance path is exercised."""
    replaced = 0
    for seed in range(10):
        rng = np.random.default_rng(seed + 500)
        city = lattice(rng, n=9, spacing=380.0)
        graph = road_graph(city)
        now = T0 + 600.0 + 3000.0 * (seed % 2)  # half of them run into the next interval
        k0 = city.horizon.interval_of(now)
        n = graph.n_nodes
        taxis = [TaxiId(f"t{t}") for t in range(int(rng.integers(3, 12)))]
        counts = CountsView(
            {IntervalKey(k0): rng.integers(0, 2, city.grid.n_cells)},
            {taxis[0]: frozenset({(IntervalKey(k0), int(c)) for c in rng.choice(city.grid.n_cells, 3)})},
        )
        counted = counted_csr(counts.visited, taxis, k0)
        gn = gain_table(city, counts.counts, k0, 3, now)
        start = []
        for i in range(len(taxis)):
            src, dst = (int(x) for x in rng.choice(n, 2, replace=False))
            ((_k, edges, _g, _t, _l),) = ref.algorithm1(
                graph, gn, zeroed(counted, i), src, [dst], now, KAPPAS
            )
            start.append((src, edges, dst))
        expect = book_algorithm2(city, graph, counts, taxis, counted, list(start), now, k0, 3)
        pool = ScratchPool(graph)
        routes, fastest = [], []
        for i, (src, edges, dst) in enumerate(start):
            with pool.take() as scratch:
                drive = Drive(i, src, dst, int(INF))
                f = route_pair(graph, gn, counted, drive, KAPPAS, 0, scratch)
                routes.append(plan_one(graph, gn, counted, drive, f, KAPPAS, now, scratch))
            fastest.append(f)
            assert routes[-1].edges.tolist() == edges
        ep = Epoch(city, graph, counts, now, k0, workers, pool)
        got = improve_routes(ep, taxis, counted, routes, fastest, 3)
        assert got[2] == expect[2]
        assert got[1] == pytest.approx(expect[1], rel=1e-12)
        assert [r.edges.tolist() for r in got[0]] == [e for _, e, _ in expect[0]]
        assert all(b >= a for a, b in zip(got[1], got[1][1:], strict=False))
        replaced += len(expect[1]) - 1
    assert replaced > 0


@pytest.mark.parametrize("seed", range(6))
def test_timed_pairs_and_g_route(seed: int) -> None:
    """The compiled timed G-route is ``sensing.timed_cells(...).pairs()`` exactly (boundary crossings,
    repeated cells, the empty path), and ``path_facts``, which decide uses for all its paths at once,
    gives each path of a batch that timed G-route and its G-route (cells in first-crossing order)."""
    rng, city, *_ = instance(seed + 900)
    graph = road_graph(city)
    ed = graph.edges
    ws = heaps.workspace(graph)
    depart = T0 + 3600.0 * (seed % 3) - float(rng.uniform(0, 400))
    batch: list[tuple[np.ndarray, list[tuple[IntervalKey, int]], list[int]]] = []
    for trial in range(20):
        src, dst = (int(x) for x in rng.choice(graph.n_nodes, 2, replace=False))
        edges = point_to_point.fastest_path(graph, ws, src, dst)
        if trial % 5 == 0:
            edges = np.concatenate([edges, edges[::-1][: len(edges) // 2]]).astype(np.int64)
        if trial == 1:
            edges = np.zeros(0, dtype=np.int64)
        pairs = timed_cells(city, edges, depart).pairs()
        assert timed_pairs(city, edges, depart) == pairs
        cells = list(
            dict.fromkeys(int(c) for e in edges for c in ed.ec_cell[ed.ec_ptr[e] : ed.ec_ptr[e + 1]])
        )
        batch.append((edges, pairs, cells))
    ptr = np.zeros(len(batch) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(e) for e, _, _ in batch])
    flat = np.concatenate([e for e, _, _ in batch]).astype(np.int64)
    shift = city.horizon.shift_s(depart)
    c_ptr, c, p_ptr, pk, pc = path_facts(
        ed, ptr, flat, depart, shift, float(city.horizon.interval_s), city.grid.n_cells
    )
    for q, (_edges, pairs, cells) in enumerate(batch):
        assert c[c_ptr[q] : c_ptr[q + 1]].tolist() == cells
        got = list(
            zip(pk[p_ptr[q] : p_ptr[q + 1]].tolist(), pc[p_ptr[q] : p_ptr[q + 1]].tolist(), strict=True)
        )
        assert got == pairs


def test_parallel_map_keeps_order_and_raises_the_first_error() -> None:
    def squares(xs):
        return [x * x for x in xs]

    assert parallel_map(squares, range(50), 3) == [x * x for x in range(50)]
    assert parallel_map(squares, [], 3) == []

    def fail(xs):
        for x in xs:
            if x in (17, 41):
                raise ValueError(f"item {x}")
        return list(xs)

    with pytest.raises(ValueError, match="item 17"):
        parallel_map(fail, range(50), 3)


def random_epochs(city, n: int, scale: int, seed: int = 7):
    rng = np.random.default_rng(seed)
    nn = city.network.n_nodes
    t0 = city.horizon.start_s("2026-11-23")
    for e in range(n):
        now = t0 + 200.0 * e
        riders = tuple(
            Rider(RiderId(f"r{e}-{i}"), int(rng.integers(nn)), int(rng.integers(nn)), now - 30.0)
            for i in range(6 * scale)
        )
        taxis = tuple(
            Taxi(TaxiId(f"i{i}"), int(rng.integers(nn)), True, True) for i in range(20 * scale)
        ) + tuple(Taxi(TaxiId(f"o{i}"), int(rng.integers(nn)), False, True) for i in range(10 * scale))
        tasks = [Task(TaskId(f"k{e}-{i}"), int(rng.integers(nn)), now - 60.0) for i in range(8 * scale)]
        yield Snapshot(f"e{e}", now, riders, taxis), tasks


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_decide_is_the_same_on_one_thread_and_several(name: str) -> None:
    """Whole epochs on the bundled cities (counts committed between them) with 1 and 3 workers."""
    city = load_city(BUNDLES / name)
    counts: dict[IntervalKey, np.ndarray] = {}
    visited: dict[str, set[tuple[IntervalKey, int]]] = {}
    for snap, tasks in random_epochs(city, 4, 3 if name == "chengdu" else 2):
        view = CountsView(dict(counts), {TaxiId(k): frozenset(v) for k, v in visited.items()})
        one = decide(city, view, snap, tasks, workers=1)
        three = decide(city, view, snap, tasks, workers=3)
        assert one == three
        assert one.task_assignments
        for v in one.visits:
            if (v.interval, v.cell) not in visited.setdefault(v.taxi_id, set()):
                visited[v.taxi_id].add((v.interval, v.cell))
                counts.setdefault(v.interval, np.zeros(city.grid.n_cells, dtype=np.int64))[v.cell] += 1


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_umax_scan_is_the_largest_entered_utility_over_every_edge(name: str) -> None:
    """``_umax_scan`` reads the cells entered by an edge alone once and sums only the edges entering
    several cells: it equals the largest unmasked sum over every edge of the network, including masks that
    zero the largest cells' terms (where an edge entering two cells may be the largest)."""
    rng = np.random.default_rng(5)
    city = load_city(BUNDLES / name)
    graph = road_graph(city)
    ed = graph.edges
    kt = algorithm1.kappa_graph(graph, KAPPAS)
    assert kt.multi.size > 0  # the case that sums
    n_cells = int(graph.n_cells)
    multi_cells = np.unique(
        np.concatenate([ed.ec_cell[ed.ec_ptr[e] + 1 : ed.ec_ptr[e + 1]] for e in kt.multi])
    )
    for damped in (1.0, 0.01):  # 0.01: the largest sums are single cells' terms, whose masks then matter
        term = rng.uniform(0.0, 1.0, (2, n_cells)) * (rng.random((2, n_cells)) < 0.7)
        term[:, multi_cells] *= damped
        check_umax_scan(
            rng, kt, gain_table(city, {}, city.horizon.interval_of(T0), 2, T0)._replace(term=term)
        )


def check_umax_scan(rng: np.random.Generator, kt: algorithm1.KappaGraph, gn) -> None:
    """``_umax_scan`` under masks of more and more of the largest terms and a few random cells, against the
    largest unmasked sum over every edge, summed in the order the edge enters its cells."""
    ed, term = kt.ed, gn.term
    n_cells = term.shape[1]
    by_term = np.argsort(-term[0])
    for trial in range(12):
        zmask = np.zeros((1, n_cells), dtype=np.bool_)
        zmask[0, by_term[: 3 * trial]] = True  # the largest terms masked, more each trial
        zmask[0, rng.choice(n_cells, trial)] = True
        brute = max(
            sum(
                (
                    float(term[0, c])
                    for c in ed.ec_cell[ed.ec_ptr[e] + 1 : ed.ec_ptr[e + 1]]
                    if not zmask[0, c]
                ),
                0.0,
            )
            for e in range(ed.time_s.shape[0])
        )
        assert algorithm1._umax_scan(kt, gn, zmask) == brute
