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


def reference_improve_routes(city, counts, routes, depart_s, n_slots):  # type: ignore[no-untyped-def]
    """Algorithm 2 as first written: the others' visits as a Counter passed to ``gain_table(extra=...)``,
    every re-plan searching all kappas (including the fastest path) from scratch."""
    from collections import Counter

    from services.routing import _joint_from_counts, plan_routes, route_pairs

    k0 = int(city.horizon.intervals_of(np.array([depart_s]))[0])
    visited = [counts.visited.get(r.taxi_id, frozenset()) for r in routes]
    pairs = [route_pairs(city, r, v, depart_s) for r, v in zip(routes, visited, strict=True)]
    total: Counter[tuple[int, int]] = Counter()
    for ps in pairs:
        total.update(ps)
    history = [_joint_from_counts(city, counts.counts, total)]
    passes = 0
    accepted = 0
    planned_at = [-1] * len(routes)
    for _ in range(city.params.max_iter):
        passes += 1
        changed = False
        for i, r in enumerate(routes):
            if planned_at[i] == accepted:
                continue
            planned_at[i] = accepted
            others = total.copy()
            others.subtract(pairs[i])
            table = gain_table(city, counts.counts, k0, n_slots, depart_s, extra=+others)
            rs, _ = plan_routes(
                city, table, r.taxi_id, r.source, visited[i], np.array([r.target], dtype=np.int64), depart_s
            )
            cand = rs.route(0)
            if np.array_equal(cand.edges, r.edges):
                continue
            cand_pairs = route_pairs(city, cand, visited[i], depart_s)
            trial = others.copy()
            trial.update(cand_pairs)
            u_new = _joint_from_counts(city, counts.counts, trial)
            if u_new > history[-1] * (1 + 1e-12) + 1e-300:
                routes[i] = cand
                pairs[i] = cand_pairs
                total = trial
                history.append(u_new)
                accepted += 1
                planned_at[i] = accepted
                changed = True
        if not changed:
            break
    return routes, history, passes


@pytest.mark.parametrize("contracted,workers", [(True, 1), (True, 2), (False, 1), (False, 3)])
def test_algorithm2_with_known_fastest_paths_and_dense_counts_equals_reference(
    contracted: bool, workers: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``improve_routes`` fed the Step 3 fastest paths (no kappa = 0 re-search), keeping the others' visits
    as a dense count and planning batches of re-plans on several threads gives the same routes, the same
    utility history (bit for bit) and the same passes as the reference; on these instances it does
    replace routes, so the acceptance path (and the re-planning of a batch after it) is exercised."""
    from services import routing
    from services.model import CountsView, TaxiId
    from services.routing import CountedIn, improve_routes, plan_routes

    monkeypatch.setattr(routing, "WORKERS", workers)
    replaced = 0
    try:
        contraction.ENABLED = contracted
        for seed in range(16):
            rng = np.random.default_rng(seed + 500)
            city = jittered_city(rng, n=9, spacing=380.0)
            now = T0 + 600.0 + 3000.0 * (seed % 2)  # half of them run into the next interval
            k0 = city.horizon.interval_of(now)
            n = city.network.n_nodes
            counts = CountsView(
                {IntervalKey(k0): rng.integers(0, 2, city.grid.n_cells)},
                {
                    TaxiId("t0"): frozenset(
                        {(IntervalKey(k0), int(c)) for c in rng.choice(city.grid.n_cells, 3)}
                    )
                },
            )
            table = gain_table(city, counts.counts, k0, 3, now)
            routes, fastest = [], []
            for t in range(int(rng.integers(3, 14))):
                tid = TaxiId(f"t{t}")
                src, dst = (int(x) for x in rng.choice(n, 2, replace=False))
                rs, _ = plan_routes(
                    city, table, tid, src, counts.visited.get(tid), np.array([dst], dtype=np.int64), now
                )
                routes.append(rs.route(0))
                fastest.append(rs.path(0, 0.0))
            expect = reference_improve_routes(city, counts, list(routes), now, 3)
            got = improve_routes(
                city, counts, list(routes), now, 3, fastest=fastest, counted=CountedIn(counts.visited, k0)
            )
            assert got[1] == expect[1] and got[2] == expect[2]
            for a, b in zip(got[0], expect[0], strict=True):
                assert np.array_equal(a.edges, b.edges)
                assert (a.kappa, a.gain, a.time_s, a.length_m) == (b.kappa, b.gain, b.time_s, b.length_m)
            replaced += len(expect[1]) - 1
    finally:
        contraction.ENABLED = True
    assert replaced > 0


@pytest.mark.parametrize("seed", range(8))
def test_timed_pairs_equal_sensing_timed_cells(seed: int) -> None:
    """The compiled timed G-route is ``sensing.timed_cells(...).pairs()`` exactly (crossing times,
    intervals near a boundary, first-entry order, repeated cells, the empty path); the G-route kernel
    gives its cells in first-crossing order."""
    from services.dispatch import _g_route
    from services.routing import timed_pairs
    from services.sensing import timed_cells

    rng = np.random.default_rng(seed + 900)
    city = jittered_city(rng, n=9, spacing=380.0)
    ga = graph_arrays(city)
    n = city.network.n_nodes
    for trial in range(25):
        depart = T0 + 3600.0 * (seed % 3) - float(rng.uniform(0, 400))
        src = int(rng.integers(n))
        _d, pred, _a = kernels.dijkstra(
            ga.indptr,
            ga.head,
            ga.time_s * rng.uniform(0.2, 1, len(ga.time_s)),
            src,
            np.inf,
            np.zeros(0, np.int64),
            ga.time_s,
        )
        edges = kernels.walk_edges(pred, ga.tail, int(rng.integers(n)))
        if trial % 5 == 0:
            edges = np.concatenate([edges, edges[::-1][: len(edges) // 2]]).astype(
                np.int64
            )  # cells crossed again
        if trial == 1:
            edges = np.zeros(0, dtype=np.int64)
        assert timed_pairs(city, edges, depart) == timed_cells(city, edges, depart).pairs()
        cells = [
            city.grid.col_row(int(c))
            for c in dict.fromkeys(
                city.edge_cells.cell[
                    np.concatenate(
                        [np.arange(city.edge_cells.ptr[e], city.edge_cells.ptr[e + 1]) for e in edges]
                        or [np.zeros(0, np.int64)]
                    )
                ].tolist()
            )
        ]
        assert list(_g_route(city, edges)) == cells


def test_parallel_map_keeps_order_and_raises_the_first_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from services import routing

    monkeypatch.setattr(routing, "WORKERS", 3)
    assert routing.parallel_map(lambda x: x * x, range(50)) == [x * x for x in range(50)]
    assert routing.parallel_map(lambda x: x, []) == []

    def fail(x: int) -> int:
        if x in (17, 41):
            raise ValueError(f"item {x}")
        return x

    with pytest.raises(ValueError, match="item 17"):
        routing.parallel_map(fail, range(50))


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_decide_is_the_same_on_one_thread_and_several(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Whole epochs on the bundled cities (counts committed between them) with WORKERS = 1 and 2."""
    from services import routing
    from services.citydata import load_city
    from services.dispatch import decide
    from services.model import CountsView
    from tests.unit.test_contraction import CITIES, random_epochs

    city = load_city(CITIES / name)
    counts: dict[IntervalKey, np.ndarray] = {}
    visited: dict[str, set[tuple[IntervalKey, int]]] = {}
    for snap, tasks in random_epochs(city, 5, 4 if name == "chengdu" else 2):
        view = CountsView(dict(counts), {k: frozenset(v) for k, v in visited.items()})  # type: ignore[misc]
        monkeypatch.setattr(routing, "WORKERS", 1)
        one = decide(city, view, snap, tasks)
        monkeypatch.setattr(routing, "WORKERS", 2)
        two = decide(city, view, snap, tasks)
        assert one == two
        assert one.task_assignments
        for v in one.visits:
            if (v.interval, v.cell) not in visited.setdefault(v.taxi_id, set()):
                visited[v.taxi_id].add((v.interval, v.cell))
                counts.setdefault(v.interval, np.zeros(city.grid.n_cells, dtype=np.int64))[v.cell] += 1
