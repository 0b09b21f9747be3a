"""The contracted search against the plain ``kernels.dijkstra``: random lattices whose edges are subdivided
into chains of shape nodes (one-way and two-way, dead ends, loops back to one junction, parallel chains and
cycles of shape nodes only), then whole epochs on the bundled Chengdu network with contraction on and off."""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from numpy.typing import NDArray

from services import contraction, kernels
from services.citydata import load_city
from services.dispatch import decide
from services.model import CountsView, IntervalKey, Rider, RiderId, Snapshot, Task, TaskId, Taxi, TaxiId
from services.routing import graph_arrays
from tests.citymaker import make_city

NONE = np.zeros(0, dtype=np.int64)
CITIES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"


class Graph:
    """A CSR graph (edges sorted by (u, v), no parallel edges, no self-loops) with per-edge lengths."""

    def __init__(self, n: int, edges: dict[tuple[int, int], float]) -> None:
        keys = sorted(edges)
        self.n = n
        self.tail = np.array([k[0] for k in keys], dtype=np.int32)
        self.head = np.array([k[1] for k in keys], dtype=np.int32)
        self.length = np.array([edges[k] for k in keys], dtype=np.float64)
        counts = np.bincount(self.tail, minlength=n)
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    def reversed(self) -> Graph:
        return Graph(
            self.n,
            {(int(v), int(u)): float(x) for u, v, x in zip(self.tail, self.head, self.length, strict=True)},
        )


def chain_graph(seed: int, side: int = 5, spacing: float = 100.0) -> Graph:
    """A jittered ``side`` x ``side`` lattice whose edges carry 0-5 shape nodes, each street two-way or
    one-way; plus dead-end spurs, loops from a junction back to itself, a parallel chain and two cycles made
    of shape nodes only (one two-way, one one-way)."""
    rng = np.random.default_rng(seed)
    pos: list[tuple[float, float]] = [
        (c * spacing + rng.uniform(-20, 20), r * spacing + rng.uniform(-20, 20))
        for r in range(side)
        for c in range(side)
    ]
    edges: dict[tuple[int, int], float] = {}

    def node(x: float, y: float) -> int:
        pos.append((x + rng.uniform(-5, 5), y + rng.uniform(-5, 5)))
        return len(pos) - 1

    def link(a: int, b: int) -> None:
        edges[(a, b)] = max(float(np.hypot(pos[a][0] - pos[b][0], pos[a][1] - pos[b][1])), 1e-3)

    def street(nodes: list[int], kind: str) -> None:
        for a, b in zip(nodes[:-1], nodes[1:], strict=True):
            if kind in ("two", "fwd"):
                link(a, b)
            if kind in ("two", "bwd"):
                link(b, a)

    def shape_nodes(a: int, b: int, k: int) -> list[int]:
        (xa, ya), (xb, yb) = pos[a], pos[b]
        return [node(xa + (xb - xa) * t, ya + (yb - ya) * t) for t in np.linspace(0, 1, k + 2)[1:-1]]

    kinds = ["two", "two", "two", "fwd", "bwd"]
    lattice = [(r * side + c, r * side + c + 1) for r in range(side) for c in range(side - 1)]
    lattice += [(r * side + c, (r + 1) * side + c) for r in range(side - 1) for c in range(side)]
    for a, b in lattice:
        street([a, *shape_nodes(a, b, int(rng.integers(0, 6))), b], kinds[int(rng.integers(len(kinds)))])
    junctions = rng.choice(side * side, size=6, replace=False).tolist()
    # dead-end spurs (two-way) with 0-3 shape nodes before the leaf
    for a in junctions[:2]:
        leaf = node(pos[a][0] + 37.0, pos[a][1] + 41.0)
        street([a, *shape_nodes(a, leaf, int(rng.integers(0, 4))), leaf], "two")
    # loops from a junction back to itself: one-way and two-way
    for a, kind in zip(junctions[2:4], ("fwd", "two"), strict=True):
        x, y = pos[a]
        loop = [node(x + 30.0, y + 10.0), node(x + 45.0, y + 35.0), node(x + 15.0, y + 40.0)]
        street([a, *loop, a], kind)
    # a second chain between two neighbouring lattice nodes (parallel super-edges)
    a = junctions[4] - (junctions[4] % side == side - 1)
    x, y = pos[a]
    street([a, node(x + 50.0, y - 30.0), node(x + 70.0, y - 25.0), a + 1], "two")
    # cycles of shape nodes only (their own components)
    for k, kind in ((4, "two"), (3, "fwd")):
        ring = [
            node(-500.0 * k + 60 * np.cos(t), -500.0 + 60 * np.sin(t)) for t in np.arange(k) * 2 * np.pi / k
        ]
        street([*ring, ring[0]], kind)
    return Graph(len(pos), edges)


def run_plain(
    g: Graph, cost: NDArray[np.float64], s: int, limit: float = np.inf, targets: NDArray[np.int64] = NONE
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    return kernels.dijkstra(g.indptr, g.head, cost, s, limit, targets, g.length)  # type: ignore[no-any-return]


def run_contracted(
    g: Graph,
    c: contraction.Contraction,
    cost: NDArray[np.float64],
    s: int,
    limit: float = np.inf,
    targets: NDArray[np.int64] = NONE,
    queries: NDArray[np.int64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    return contraction.search(c, cost, s, limit, targets, g.length, queries)


def interior_sources(c: contraction.Contraction, rng: np.random.Generator, k: int) -> list[int]:
    inner = np.flatnonzero(c.kept_of < 0)
    kept = c.kept
    return [int(x) for x in rng.choice(inner, k, replace=False)] + [int(x) for x in rng.choice(kept, k)]


def chain_mates(c: contraction.Contraction, v: int) -> list[int]:
    """Every node on the super-edges through ``v`` (both ends included), or on those leaving ``v``."""
    if c.kept_of[v] >= 0:
        k = int(c.kept_of[v])
        ses = list(range(int(c.indptr[k]), int(c.indptr[k + 1])))
    else:
        ses = [int(s) for s in c.pos_se[v] if s >= 0]
    out: set[int] = set()
    for s in ses:
        out.add(int(c.kept[c.se_tail[s]]))
        out.update(int(x) for x in c.se_node[c.se_ptr[s] : c.se_ptr[s + 1]])
    return sorted(out)


# ---------------------------------------------------------------- structure


@pytest.mark.parametrize("seed", range(8))
def test_contraction_structure(seed: int) -> None:
    g = chain_graph(seed)
    c = contraction.contract(g.indptr, g.head)
    n, m = g.n, len(g.head)
    # every original edge lies on exactly one super-edge, and super-edges are paths between kept nodes
    assert np.array_equal(np.sort(c.se_edges), np.arange(m))
    assert np.array_equal(c.se_node, g.head[c.se_edges])
    for s in range(c.n_super_edges):
        es = c.se_edges[c.se_ptr[s] : c.se_ptr[s + 1]]
        assert g.tail[es[0]] == c.kept[c.se_tail[s]] and g.head[es[-1]] == c.kept[c.se_head[s]]
        assert np.array_equal(g.head[es[:-1]], g.tail[es[1:]])
        assert (c.kept_of[g.head[es[:-1]]] < 0).all()
        if c.se_rev[s] >= 0:
            r = int(c.se_rev[s])
            assert c.se_rev[r] == s
            back = c.se_edges[c.se_ptr[r] : c.se_ptr[r + 1]]
            assert np.array_equal(g.tail[back][::-1], g.head[es])
    assert np.array_equal(
        c.indptr, np.concatenate([[0], np.cumsum(np.bincount(c.se_tail, minlength=c.n_kept))])
    )
    assert (np.diff(c.se_tail) >= 0).all()
    # interior nodes are exactly the chain nodes of the definition, except one node per cycle of them
    out_n = [set(g.head[g.indptr[v] : g.indptr[v + 1]].tolist()) for v in range(n)]
    in_n: list[set[int]] = [set() for _ in range(n)]
    for u, v in zip(g.tail.tolist(), g.head.tolist(), strict=True):
        in_n[v].add(u)
    chain = np.array(
        [
            (len(in_n[v]) == len(out_n[v]) == 1 and in_n[v] != out_n[v])
            or (len(in_n[v]) == len(out_n[v]) == 2 and in_n[v] == out_n[v])
            for v in range(n)
        ]
    )
    interior = c.kept_of < 0
    assert not (interior & ~chain).any()
    assert (chain & ~interior).sum() == 2  # one kept node on each of the two cycles of shape nodes
    assert np.array_equal(c.kept, np.flatnonzero(~interior))
    dead_end = np.array([len(in_n[v]) == len(out_n[v]) == 1 and in_n[v] == out_n[v] for v in range(n)])
    assert np.array_equal(c.dead_end, dead_end[c.kept]) and c.dead_end.sum() >= 2  # the spurs' leaves
    for v in np.flatnonzero(interior):
        ses = [int(s) for s in c.pos_se[v] if s >= 0]
        assert len(ses) == (2 if len(in_n[v]) == 2 else 1) and ses == sorted(ses)
        for j, s in enumerate(ses):
            assert c.se_node[c.se_ptr[s] + c.pos_off[v, j] - 1] == v
    assert c.n_kept < n and c.n_super_edges < m


def test_a_cycle_of_shape_nodes_only() -> None:
    # a two-way ring 0-1-2-3-4-0: every node is a chain interior; one is kept
    edges = {(i, (i + 1) % 5): 1.0 + i / 7 for i in range(5)} | {
        ((i + 1) % 5, i): 2.0 + i / 11 for i in range(5)
    }
    g = Graph(5, edges)
    c = contraction.contract(g.indptr, g.head)
    assert c.n_kept == 1 and c.n_super_edges == 2
    everyone = np.arange(5, dtype=np.int64)
    for s in range(5):
        expect = run_plain(g, g.length, s)
        got = run_contracted(g, c, g.length, s, queries=everyone)
        for a, b in zip(expect, got, strict=True):
            np.testing.assert_array_equal(a, b)


# ---------------------------------------------------------------- the search against the plain kernel


def assert_same(
    expect: tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]],
    got: tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]],
    nodes: NDArray[np.int64] | slice,
) -> None:
    np.testing.assert_array_equal(got[0][nodes], expect[0][nodes])
    np.testing.assert_array_equal(got[1][nodes], expect[1][nodes])
    np.testing.assert_array_equal(got[2][nodes], expect[2][nodes])


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("direction", ["forward", "reverse"])
def test_full_trees_are_identical(seed: int, direction: str) -> None:
    g = chain_graph(seed)
    if direction == "reverse":
        g = g.reversed()
    c = contraction.contract(g.indptr, g.head)
    rng = np.random.default_rng(seed + 100)
    cost = g.length * rng.uniform(0.3, 1.0, len(g.length))
    everyone = np.arange(g.n, dtype=np.int64)
    for s in interior_sources(c, rng, 6):
        assert_same(run_plain(g, cost, s), run_contracted(g, c, cost, s, queries=everyone), slice(None))
        # a radius: a node is written iff its exact distance is within the limit
        full = run_plain(g, cost, s)[0]
        reach = full[np.isfinite(full)]
        for limit in (float(np.median(reach)), float(rng.choice(reach)), 0.0):
            expect = run_plain(g, cost, s, limit)
            got = run_contracted(g, c, cost, s, limit, queries=everyone)
            assert_same(expect, got, slice(None))
            assert (np.isfinite(got[0]) == (full <= limit)).all()


@pytest.mark.parametrize("seed", range(12))
def test_targets_and_queries_are_identical(seed: int) -> None:
    g = chain_graph(seed)
    c = contraction.contract(g.indptr, g.head)
    rng = np.random.default_rng(seed + 200)
    cost = g.length * rng.uniform(0.3, 1.0, len(g.length))
    for s in interior_sources(c, rng, 8):
        # random targets, the source itself and every node on the source's own chain(s)
        mates = chain_mates(c, s)
        for targets in (
            rng.integers(g.n, size=int(rng.integers(1, 6))),
            np.array([s]),
            np.array(mates),
            np.array([*rng.integers(g.n, size=3), s, *mates]),
        ):
            targets = targets.astype(np.int64)
            expect = run_plain(g, cost, s, np.inf, targets)
            got = run_contracted(g, c, cost, s, np.inf, targets)
            assert_same(expect, got, targets)
            for t in targets:
                np.testing.assert_array_equal(
                    kernels.walk_edges(got[1], g.tail, int(t)), kernels.walk_edges(expect[1], g.tail, int(t))
                )
        # queries other than the targets (the pickup search: a radius and the taxis' nodes)
        queries = rng.integers(g.n, size=10).astype(np.int64)
        limit = float(np.median(run_plain(g, cost, s)[0][np.isfinite(run_plain(g, cost, s)[0])]))
        expect = run_plain(g, cost, s, limit)
        got = run_contracted(g, c, cost, s, limit, NONE, queries)
        assert_same(expect, got, queries)


@pytest.mark.parametrize("seed", range(6))
def test_every_pair_on_the_same_chain(seed: int) -> None:
    g = chain_graph(seed, side=4)
    c = contraction.contract(g.indptr, g.head)
    cost = g.length * np.random.default_rng(seed).uniform(0.3, 1.0, len(g.length))
    for s in np.flatnonzero(c.kept_of < 0).tolist():
        mates = np.array(chain_mates(c, s), dtype=np.int64)
        expect = run_plain(g, cost, s)
        for t in mates:
            got = run_contracted(g, c, cost, s, np.inf, np.array([t]))
            assert_same(expect, got, np.array([t]))


def tree_path(pred: NDArray[np.int64], g: Graph, s: int, v: int) -> list[int]:
    """Edges of the tree path to ``v``; fails on a cycle."""
    out: list[int] = []
    while v != s:
        e = int(pred[v])
        assert e >= 0 and len(out) <= len(g.head), "broken or cyclic tree"
        out.append(e)
        v = int(g.tail[e])
    return out[::-1]


@pytest.mark.parametrize("seed", range(10))
def test_ties_and_zero_costs_give_valid_shortest_paths(seed: int) -> None:
    # small integer costs, many of them 0: paths may differ from the plain search, distances may not
    g = chain_graph(seed)
    c = contraction.contract(g.indptr, g.head)
    rng = np.random.default_rng(seed + 300)
    cost = rng.integers(0, 3, len(g.length)).astype(np.float64)
    everyone = np.arange(g.n, dtype=np.int64)
    for s in interior_sources(c, rng, 6):
        expect = run_plain(g, cost, s)
        for queries in (everyone, rng.integers(g.n, size=7).astype(np.int64)):
            dist, pred, acc = run_contracted(g, c, cost, s, np.inf, queries[:3], queries)
            np.testing.assert_array_equal(dist[queries[:3]], expect[0][queries[:3]])
            # past the targets the search may have stopped: a query is then unknown, never wrong
            known = np.isfinite(dist[queries])
            np.testing.assert_array_equal(dist[queries][known], expect[0][queries][known])
            for v in queries.tolist():
                if not np.isfinite(dist[v]):
                    continue
                edges = tree_path(pred, g, s, v)
                d, a = 0.0, 0.0
                for e in edges:
                    d += cost[e]
                    a += g.length[e]
                assert d == dist[v] and a == acc[v]


# ---------------------------------------------------------------- through the city wrapper and decide()


def test_city_wrapper_switch() -> None:
    rng = np.random.default_rng(5)
    nodes = {i: (float(x), float(y)) for i, (x, y) in enumerate(rng.uniform(0, 3000, (30, 2)))}
    ring = [(i, (i + 1) % 30) for i in range(30)]  # a ring with chords: most nodes are chain interiors
    city = make_city(nodes, ring + [(0, 10), (10, 20), (5, 25)])
    ga = graph_arrays(city)
    assert contraction.forward(ga) is contraction.forward(ga)
    assert contraction.forward(ga).n_kept == 5 and contraction.reverse(ga).n_kept == 5
    taxis = np.arange(30, dtype=np.int64)
    for s in range(30):
        for kw in ({"reverse_graph": False}, {"reverse_graph": True}):
            cost, aux = (ga.rev_time_s, ga.rev_length_m) if kw["reverse_graph"] else (ga.time_s, ga.length_m)
            a = contraction.dijkstra(ga, cost, s, 300.0, NONE, aux, queries=taxis, contracted=False, **kw)
            b = contraction.dijkstra(ga, cost, s, 300.0, NONE, aux, queries=taxis, contracted=True, **kw)
            assert_same(a, b, slice(None))


def random_epochs(city, seed: int, n: int) -> list[tuple[Snapshot, list[Task]]]:  # type: ignore[no-untyped-def]
    """Epochs like the benchmark's paper scenario: 60 + 60 vacant taxis, ~10 riders, up to 85 open tasks."""
    rng = np.random.default_rng(seed)
    nn = city.network.n_nodes
    t0 = dt.datetime(2026, 11, 23, 8, 0, tzinfo=ZoneInfo(city.horizon.timezone)).timestamp()
    out = []
    for e in range(n):
        now = t0 + e * 200.0
        riders = tuple(
            Rider(
                RiderId(f"r{e}-{i}"),
                int(rng.integers(nn)),
                int(rng.integers(nn)),
                now - float(rng.uniform(0, 300)),
            )
            for i in range(int(rng.poisson(10)))
        )
        taxis = tuple(Taxi(TaxiId(f"i{i}"), int(rng.integers(nn)), True, True) for i in range(60)) + tuple(
            Taxi(TaxiId(f"o{i}"), int(rng.integers(nn)), False, True) for i in range(60)
        )
        tasks = [
            Task(TaskId(f"k{e}-{i}"), int(rng.integers(nn)), now - 60.0) for i in range(int(rng.integers(86)))
        ]
        out.append((Snapshot(f"e{e}", now, riders, taxis), tasks))
    return out


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_decide_is_identical_with_and_without_contraction(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    city = load_city(CITIES / name)
    assert contraction.ENABLED
    counts: dict[IntervalKey, NDArray[np.int64]] = {}
    visited: dict[TaxiId, set[tuple[IntervalKey, int]]] = {}
    n_epochs = 10 if name == "chengdu" else 3
    kappas: set[float] = set()
    for snap, tasks in random_epochs(city, 11, n_epochs):
        view = CountsView(dict(counts), {k: frozenset(v) for k, v in visited.items()})
        monkeypatch.setattr(contraction, "ENABLED", True)
        on = decide(city, view, snap, tasks)
        monkeypatch.setattr(contraction, "ENABLED", False)
        off = decide(city, view, snap, tasks)
        assert on.rider_matches == off.rider_matches
        assert on.task_assignments == off.task_assignments
        assert on.task_updates == off.task_updates
        assert on == off
        assert on.rider_matches and on.task_assignments
        kappas.update(a.kappa for a in on.task_assignments)
        for v in on.visits:  # commit, so counts evolve as they would in service
            if (v.interval, v.cell) not in visited.setdefault(v.taxi_id, set()):
                visited[v.taxi_id].add((v.interval, v.cell))
                counts.setdefault(v.interval, np.zeros(city.grid.n_cells, dtype=np.int64))[v.cell] += 1
    assert len(kappas) > 1  # utility-discounted routes were compared too, not only fastest paths
