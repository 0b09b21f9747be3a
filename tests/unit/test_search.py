"""Canonical shortest paths: the contracted search against a plain lexicographic Dijkstra written here.

The reference settles every original node with labels (cost, tie1, tie2) compared in order, so its tree
is *the* canonical one; the compiled search must give the same label and the same path to every node,
forward and reverse, from kept and interior sources, with and without a limit or early-exit targets.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.citydata import load_city
from services.network import astar, dijkstra, heaps, point_to_point, unfolding
from services.network.graph import INF, RoadGraph, prepare, road_graph
from tests.citymaker import make_city
from tests.reference import canonical_tree as reference_tree
from tests.reference import tree_path

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"


def chain_city():
    """A ring of degree-2 nodes with two spurs, a one-way chain and a dead end: every contraction case."""
    nodes = {
        i: (100.0 * np.cos(i / 12 * 2 * np.pi) * 10, 100.0 * np.sin(i / 12 * 2 * np.pi) * 10)
        for i in range(12)
    }
    nodes.update(
        {20: (2500.0, 0.0), 21: (3500.0, 0.0), 22: (3500.0, 900.0), 23: (2500.0, 900.0), 30: (4500.0, 0.0)}
    )
    edges = [(i, (i + 1) % 12) for i in range(12)] + [
        (0, 20),
        (20, 21),
        (21, 22),
        (22, 23),
        (23, 20),
        (21, 30),
    ]
    city = make_city(nodes, edges)
    return city


CITIES = {
    "chain": chain_city,
    "chengdu": lambda: load_city(BUNDLES / "chengdu"),
    "manhattan": lambda: load_city(BUNDLES / "manhattan"),
}


@pytest.fixture(scope="module", params=sorted(CITIES))
def graph(request):
    return road_graph(CITIES[request.param]())


def _costs(graph: RoadGraph, kind: str) -> np.ndarray:
    if kind == "time":
        return graph.edges.time_us
    rng = np.random.default_rng(7)
    # utility-discounted costs (Algorithm 1) and a grid-like case with massive ties (all costs equal)
    if kind == "discounted":
        return np.maximum(1, (graph.edges.time_us * (1 - 0.9 * rng.random(graph.n_edges))).astype(np.int64))
    if kind == "spread":  # too spread for the bucket queue: the heap takes over
        cost = (10.0 ** rng.uniform(3, 9, size=graph.n_edges)).astype(np.int64)
        cost[rng.integers(graph.n_edges, size=3)] = 1
        return cost
    return np.full(graph.n_edges, 1000, dtype=np.int64)


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("kind", ["time", "discounted", "equal", "spread"])
def test_every_node_gets_the_reference_label_and_path(graph, reverse, kind):
    g = graph.reverse if reverse else graph.forward
    cost = _costs(graph, kind)
    costs = prepare(g, cost)
    assert (costs.span > heaps.RING) == (kind == "spread")
    ws = heaps.workspace(graph, reverse)
    rng = np.random.default_rng(3)
    interior = np.flatnonzero(g.kept_of < 0)
    sources = list(rng.choice(graph.n_nodes, size=3, replace=False))
    if interior.size:
        sources += list(rng.choice(interior, size=min(3, interior.size), replace=False))
    everyone = np.arange(graph.n_nodes, dtype=np.int64)
    out = np.zeros(graph.n_nodes, dtype=np.int64)
    for s in sources:
        label, pred = reference_tree(graph, cost, int(s), reverse)
        unfolding.tree(g, graph.edges, costs, int(s), int(INF), np.zeros(0, np.int64), everyone, ws, out)
        for v in range(graph.n_nodes):
            if label[v] is None:
                assert out[v] >= INF
                continue
            got = unfolding.resolve(g, graph.edges, costs, int(INF), v, ws)
            assert got[:3] == label[v]
            path = unfolding.path_to(graph.edges, g.towards, ws.pred, int(s), v).tolist()
            assert path == tree_path(graph, pred, int(s), v, reverse)


def test_targets_and_limit_give_the_same_paths(graph):
    g = graph.forward
    cost = graph.edges.time_us
    costs = prepare(g, cost)
    ws = heaps.workspace(graph)
    rng = np.random.default_rng(11)
    for s in rng.choice(graph.n_nodes, size=5, replace=False):
        label, pred = reference_tree(graph, cost, int(s))
        reached = [v for v in range(graph.n_nodes) if label[v] is not None]
        targets = rng.choice(reached, size=min(7, len(reached)), replace=False).astype(np.int64)
        out = np.zeros(len(targets), dtype=np.int64)
        unfolding.tree(g, graph.edges, costs, int(s), int(INF), targets, targets, ws, out)
        for t, c in zip(targets, out, strict=True):
            assert c == label[int(t)][0]
            assert unfolding.path_to(graph.edges, 1, ws.pred, int(s), int(t)).tolist() == tree_path(
                graph, pred, int(s), int(t), False
            )
        limit = int(np.median([label[v][0] for v in reached]))
        every = np.arange(graph.n_nodes, dtype=np.int64)
        out = np.zeros(graph.n_nodes, dtype=np.int64)
        unfolding.tree(g, graph.edges, costs, int(s), limit, np.zeros(0, np.int64), every, ws, out)
        for v in range(graph.n_nodes):
            if label[v] is not None and label[v][0] <= limit:
                assert out[v] == label[v][0]
            else:
                assert out[v] >= INF


@pytest.mark.parametrize("reverse", [False, True])
def test_many_nodes_in_one_call_read_as_one_by_one(graph, reverse):
    """``labels`` and ``unfold_many`` (the batched reads of the hot loops) give every node -- kept, interior,
    the source, beyond the limit -- the label ``resolve`` gives it, the reach ``unfold`` gives it, and the
    same tree paths, from kept and interior sources."""
    g = graph.reverse if reverse else graph.forward
    cost = _costs(graph, "discounted")
    costs = prepare(g, cost)
    ws = heaps.workspace(graph, reverse)
    rng = np.random.default_rng(23)
    interior = np.flatnonzero(g.kept_of < 0)
    sources = list(rng.choice(graph.n_nodes, size=3, replace=False))
    if interior.size:
        sources += list(rng.choice(interior, size=min(2, interior.size), replace=False))
    every = np.arange(graph.n_nodes, dtype=np.int64)
    for s in sources:
        s = int(s)
        label, _pred = reference_tree(graph, cost, s, reverse)
        limit = int(np.median([x[0] for x in label if x is not None]))
        dijkstra.run(g, graph.edges, costs, s, limit, np.zeros(0, np.int64), ws)
        one = [unfolding.resolve(g, graph.edges, costs, limit, v, ws)[:3] for v in range(graph.n_nodes)]
        many = np.zeros((3, graph.n_nodes), dtype=np.int64)
        unfolding.labels(g, graph.edges, costs, limit, every, ws, many)
        assert [tuple(c) for c in many.T.tolist()] == [tuple(x) for x in one]
        assert any(x[0] >= INF for x in one) and any(x[0] < INF for x in one)
        reached = np.zeros(graph.n_nodes, dtype=np.bool_)
        order = rng.permutation(graph.n_nodes).astype(np.int64)
        all_reached = unfolding.unfold_many(g, graph.edges, costs, limit, order, ws, reached)
        assert reached.tolist() == [one[v][0] < INF for v in order.tolist()]
        assert not all_reached
        paths = {
            v: unfolding.path_to(graph.edges, g.towards, ws.pred, s, v).tolist()
            for v in order.tolist()
            if one[v][0] < INF
        }
        dijkstra.run(g, graph.edges, costs, s, limit, np.zeros(0, np.int64), ws)
        for v, path in paths.items():
            assert unfolding.unfold(g, graph.edges, costs, limit, v, ws)
            assert unfolding.path_to(graph.edges, g.towards, ws.pred, s, v).tolist() == path


def test_forward_and_reverse_trees_give_one_path(graph):
    """The point of canonical labels: the path from a to b is the same searched from either end."""
    rng = np.random.default_rng(5)
    cost = _costs(graph, "equal")  # the worst case for ties
    fw = heaps.workspace(graph)
    rv = heaps.workspace(graph, reverse=True)
    cf = prepare(graph.forward, cost)
    cr = prepare(graph.reverse, cost)
    pairs = rng.choice(graph.n_nodes, size=(10, 2))
    for a, b in pairs.tolist():
        one = np.array([b], dtype=np.int64)
        out = np.zeros(1, dtype=np.int64)
        unfolding.tree(graph.forward, graph.edges, cf, a, int(INF), one, one, fw, out)
        if out[0] >= INF:
            continue
        p1 = unfolding.path_to(graph.edges, 1, fw.pred, a, b)
        src = np.array([a], dtype=np.int64)
        unfolding.tree(graph.reverse, graph.edges, cr, b, int(INF), src, src, rv, out)
        p2 = unfolding.walk(graph.edges, rv.pred, a, b)
        assert p1.tolist() == p2.tolist()


@pytest.mark.parametrize("kind", ["discounted", "equal"])
def test_a_goal_directed_search_finds_the_same_path(graph, kind):
    """``run_guided`` under a metric raised on some edges, guided by the exact distances to the target
    under the lower metric (what Algorithm 1's in-trees give), labels and unfolds the target exactly as
    ``run`` does -- ties included -- while settling fewer nodes; nodes that cannot reach the target
    (potential INF) are never settled. A zero potential is a plain Dijkstra on the same keys."""
    rng = np.random.default_rng(17)
    low = _costs(graph, kind)
    high = low.copy()
    raised = rng.random(graph.n_edges) < 0.2
    high[raised] += rng.integers(0, 3, int(raised.sum())) * low[raised]
    fw, rv = heaps.workspace(graph), heaps.workspace(graph, reverse=True)
    c_high = prepare(graph.forward, high)
    c_low_rev = prepare(graph.reverse, low)
    interior = np.flatnonzero(graph.forward.kept_of < 0)
    ends = list(rng.choice(graph.n_nodes, size=(6, 2)))
    if interior.size:
        ends += [(int(rng.choice(interior)), int(rng.choice(graph.n_nodes))) for _ in range(3)]
        ends += [(int(rng.choice(graph.n_nodes)), int(rng.choice(interior))) for _ in range(3)]
    kept = graph.forward.kept
    fewer = 0
    for a, b in ends:
        a, b = int(a), int(b)
        dijkstra.run(graph.reverse, graph.edges, c_low_rev, b, int(INF), np.zeros(0, np.int64), rv)
        pot = np.array(
            [
                unfolding.resolve(graph.reverse, graph.edges, c_low_rev, int(INF), int(v), rv)[:3]
                for v in kept
            ],
            dtype=np.int64,
        ).T.copy()
        zero = np.zeros_like(pot)
        zero[0] = np.where(pot[0] < INF, 0, INF)

        one = np.array([b], dtype=np.int64)
        dijkstra.run(graph.forward, graph.edges, c_high, a, int(INF), one, fw)
        want = unfolding.resolve(graph.forward, graph.edges, c_high, int(INF), b, fw)
        plain_settled = int((fw.state[fw.touched[: fw.info[2]]] == -2).sum())
        reached = unfolding.unfold(graph.forward, graph.edges, c_high, int(INF), b, fw)
        want_path = unfolding.path_to(graph.edges, 1, fw.pred, a, b).tolist() if reached else None
        for p in (pot, zero):
            astar.run_guided(graph.forward, graph.edges, c_high, a, b, p, fw, np.zeros((0, 0), np.int64))
            assert unfolding.resolve(graph.forward, graph.edges, c_high, int(INF), b, fw)[:3] == want[:3]
            touched = fw.touched[: fw.info[2]]
            settled = touched[fw.state[touched] == -2]
            assert (p[0, settled] < INF).all()
            if p is pot:
                fewer += int(len(settled) < plain_settled)
            assert unfolding.unfold(graph.forward, graph.edges, c_high, int(INF), b, fw) == reached
            if reached:
                assert unfolding.path_to(graph.edges, 1, fw.pred, a, b).tolist() == want_path
    assert fewer > 0


def test_fastest_paths_guided_by_landmarks_are_the_plain_ones(graph):
    """Riders' trips and pickup legs search goal-directed toward the target by the landmarks' bounds
    (``point_to_point.landmarks``): the same canonical paths as plain searches, on every city -- interior ends
    included. The bound is a potential: never above the true travel time (INF exactly where the target
    cannot be reached), never dropping along an edge by more than the edge's time."""
    ed = graph.edges
    lm = point_to_point.landmarks(graph)
    assert lm.shape == (graph.n_nodes, 2 * min(point_to_point.LANDMARKS, graph.n_nodes))
    assert point_to_point.landmarks(graph) is lm  # built once per graph
    rng = np.random.default_rng(23)
    rv = heaps.workspace(graph, reverse=True)
    nodes = np.arange(graph.n_nodes, dtype=np.int64)
    exact = np.empty((3, graph.n_nodes), dtype=np.int64)
    for t in rng.choice(graph.n_nodes, 4).tolist():
        dijkstra.run(graph.reverse, ed, graph.time_reverse, t, int(INF), np.zeros(0, np.int64), rv)
        unfolding.labels(graph.reverse, ed, graph.time_reverse, int(INF), nodes, rv, exact)
        bound = np.array([astar._bound(lm, lm[t], v) for v in range(graph.n_nodes)], dtype=np.int64)
        assert ((bound <= exact[0]) | (exact[0] >= INF)).all()
        assert ((bound < INF) | (exact[0] >= INF)).all() and bound[t] == 0
        finite = bound[ed.head] < INF
        assert (bound[ed.tail][finite] <= ed.time_us[finite] + bound[ed.head][finite]).all()
    interior = np.flatnonzero(graph.forward.kept_of < 0)
    src = rng.choice(graph.n_nodes, 40)
    dst = rng.choice(graph.n_nodes, 40)
    if interior.size:
        src[:10] = rng.choice(interior, 10)
        dst[5:15] = rng.choice(interior, 10)
    plain = np.zeros((0, 0), dtype=np.int64)
    ws = heaps.workspace(graph)
    for a, b in zip(src.tolist(), dst.tolist(), strict=True):
        one, other = np.array([a]), np.array([b])
        got = unfolding.paths(graph.forward, ed, graph.time_forward, ws, one, other, lm)
        want = unfolding.paths(graph.forward, ed, graph.time_forward, ws, one, other, plain)
        assert got[0].tolist() == want[0].tolist() and got[1].tolist() == want[1].tolist()


def test_landmark_guided_paths_on_one_way_streets_and_an_unreachable_part():
    """Where not every node reaches every other (one-way streets, a part with no way in or out), the
    landmarks' bound is INF exactly for nodes that cannot reach the target through a landmark the target
    reaches, and guided searches agree with plain ones on every ordered pair: the same path, or the same
    failure to join."""
    nodes = {i: (100.0 * (i % 4), 100.0 * (i // 4)) for i in range(12)}  # a 4 x 3 lattice, 100 m blocks
    nodes |= {20: (1000.0, 0.0), 21: (1100.0, 0.0), 22: (1100.0, 100.0)}  # an island
    one_way = [(3, 7), (7, 11), (11, 10), (20, 21), (21, 22)]  # the east side and the island's street
    two_way = [(i, i + 1) for i in range(12) if i % 4 != 3] + [(i, i + 4) for i in range(8)]
    two_way = [e for e in two_way if e not in {(3, 7), (7, 11), (10, 11)}]
    city = make_city(nodes, [*two_way, *[(v, u) for u, v in two_way], *one_way], both_ways=False)
    graph = road_graph(city)
    lm = point_to_point.landmarks(graph, count=3)
    assert (lm[12:] >= INF).any() and (lm[:12] < INF).all()  # the island reaches no landmark
    ws = heaps.workspace(graph)
    plain = np.zeros((0, 0), dtype=np.int64)
    joined = failed = 0
    for a in range(graph.n_nodes):
        for b in range(graph.n_nodes):
            one, other = np.array([a]), np.array([b])
            got = unfolding.paths(graph.forward, graph.edges, graph.time_forward, ws, one, other, lm)
            want = unfolding.paths(graph.forward, graph.edges, graph.time_forward, ws, one, other, plain)
            assert got[0].tolist() == want[0].tolist() and got[1].tolist() == want[1].tolist(), (a, b)
            joined += int(want[0][1] >= 0)
            failed += int(want[0][1] < 0)
    assert joined and failed  # both kinds of pair occur
