"""The contraction of degree-2 chains and the canonical search on it: random lattices whose edges are
subdivided into chains of shape nodes (one-way and two-way, dead ends, loops back to one junction, parallel
chains and cycles of shape nodes only). The structure is checked against the definition; every search
(full, bounded by a limit, stopped at targets, from kept and from interior sources, forward and reverse)
against the plain lexicographic Dijkstra on the original edges (``tests.reference.canonical_tree``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.network import contraction, heaps, unfolding
from services.network.graph import INF, RoadGraph, build_road_graph, prepare, road_graph
from tests.citymaker import make_city
from tests.reference import canonical_tree, tree_path
from tests.reference_contraction import plain_contract

NONE = np.zeros(0, dtype=np.int64)
BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"


class Graph:
    """A CSR graph (edges sorted by (u, v), no parallel edges, no self-loops) with per-edge lengths."""

    pos: list[tuple[float, float]]

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
    graph = Graph(len(pos), edges)
    graph.pos = pos
    return graph


def as_road_graph(g: Graph) -> RoadGraph:
    """The chain graph as a city's road graph (the same nodes and edges, in the same order)."""
    edges = [(int(u), int(v), float(x)) for u, v, x in zip(g.tail, g.head, g.length, strict=True)]
    city = make_city(dict(enumerate(g.pos)), edges, both_ways=False)
    graph = road_graph(city)
    assert np.array_equal(graph.edges.tail, g.tail) and np.array_equal(graph.edges.head, g.head)
    return graph


def interior_sources(c, rng: np.random.Generator, k: int) -> list[int]:
    inner = np.flatnonzero(c.kept_of < 0)
    kept = c.kept
    return [int(x) for x in rng.choice(inner, k, replace=False)] + [int(x) for x in rng.choice(kept, k)]


def chain_mates(c, v: int) -> list[int]:
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


def check(graph: RoadGraph, cost, s: int, reverse: bool, limit: int, targets, queries) -> None:
    """The search's label and path of every query equal the plain lexicographic Dijkstra's; a query beyond
    the limit is unreached, and after an early stop a query that is not a target may read as unreached
    (never wrong)."""
    g = graph.reverse if reverse else graph.forward
    costs = prepare(g, np.asarray(cost, dtype=np.int64))
    ws = heaps.workspace(graph, reverse)
    out = np.zeros(len(queries), dtype=np.int64)
    unfolding.tree(g, graph.edges, costs, s, limit, targets, queries, ws, out)
    label, pred = canonical_tree(graph, cost, s, reverse)
    stopped = ws.info[1] == 0
    for q, got in zip(queries.tolist(), out.tolist(), strict=True):
        exact = label[q] is not None and label[q][0] <= limit
        if got >= INF:
            assert not exact or (stopped and q not in set(targets.tolist()))
            continue
        assert exact and got == label[q][0]
        assert unfolding.resolve(g, graph.edges, costs, limit, q, ws)[:3] == label[q]
        assert unfolding.path_to(graph.edges, g.towards, ws.pred, s, q).tolist() == tree_path(
            graph, pred, s, q, reverse
        )


# ---------------------------------------------------------------- structure


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("renumber", [False, True])
def test_contraction_structure(seed: int, renumber: bool) -> None:
    g = chain_graph(seed)
    c = contraction.contract(g.indptr, g.head)
    if renumber:  # kept nodes in any order: the same structure
        c = contraction.renumbered(c, np.random.default_rng(seed).permutation(c.n_kept))
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
    assert np.array_equal(np.sort(c.kept), np.flatnonzero(~interior))
    assert np.array_equal(c.kept_of[c.kept], np.arange(c.n_kept))
    dead_end = np.array([len(in_n[v]) == len(out_n[v]) == 1 and in_n[v] == out_n[v] for v in range(n)])
    assert np.array_equal(c.dead_end, dead_end[c.kept]) and c.dead_end.sum() >= 2  # the spurs' leaves
    for v in np.flatnonzero(interior):
        ses = [int(s) for s in c.pos_se[v] if s >= 0]
        assert len(ses) == (2 if len(in_n[v]) == 2 else 1) and ses == sorted(ses)
        for j, s in enumerate(ses):
            assert c.se_node[c.se_ptr[s] + c.pos_off[v, j] - 1] == v
    assert c.n_kept < n and c.n_super_edges < m


@pytest.mark.parametrize("seed", range(4))
def test_renumbering_back_gives_the_contraction_again(seed: int) -> None:
    g = chain_graph(seed)
    c = contraction.contract(g.indptr, g.head)
    order = np.random.default_rng(seed).permutation(c.n_kept)
    r = contraction.renumbered(c, order)
    assert np.array_equal(r.kept, c.kept[order])
    back = contraction.renumbered(r, np.argsort(order))
    for name in c.__slots__:
        assert np.array_equal(getattr(back, name), getattr(c, name)), name
    with pytest.raises(ValueError, match="permutation"):
        contraction.renumbered(c, np.zeros(c.n_kept, dtype=np.int64))


def test_the_hilbert_key_steps_to_a_neighbour() -> None:
    # a 16 x 16 lattice of cell centres, the bounding box pinned by two corners: sorted by key, each
    # point is a lattice neighbour of the one before (the curve at its fourth level)
    side, step = 16, 4096
    ij = np.array([(i, j) for i in range(side) for j in range(side)])
    x = np.concatenate([[0.0, 65535.0], ij[:, 0] * step + step / 2])
    y = np.concatenate([[0.0, 65535.0], ij[:, 1] * step + step / 2])
    key = contraction.hilbert_key(x, y)[2:]
    assert np.unique(key).size == side * side
    walk = ij[np.argsort(key)]
    assert (np.abs(np.diff(walk, axis=0)).sum(axis=1) == 1).all()
    assert contraction.hilbert_key(np.zeros(0), np.zeros(0)).shape == (0,)


def test_the_search_graphs_number_kept_nodes_along_the_curve() -> None:
    from services.citydata import load_city

    net = load_city(BUNDLES / "chengdu").network
    graph = road_graph(load_city(BUNDLES / "chengdu"))
    kept = graph.forward.kept
    assert np.array_equal(graph.reverse.kept, kept)
    assert (np.diff(contraction.hilbert_key(net.x_m[kept], net.y_m[kept])) >= 0).all()
    # OpenStreetMap numbers nodes by when they were mapped: the super-edges' ends lie closer in the kept
    # nodes' order than in the order of their ids
    fg = graph.forward
    by_id = np.argsort(np.argsort(kept))
    gap = np.median(np.abs(fg.se_tail - fg.se_head))
    assert gap * 5 < np.median(np.abs(by_id[fg.se_tail] - by_id[fg.se_head]))


@pytest.mark.parametrize("reverse", [False, True])
def test_numbering_along_the_curve_changes_no_search(reverse: bool) -> None:
    # Chengdu's search graphs numbered along the curve and in the order of the network's nodes: from each
    # source (kept and interior), every node's cost and tie words, and the paths, are the same
    from services.citydata import load_city

    city = load_city(BUNDLES / "chengdu")
    graphs = [build_road_graph(city), build_road_graph(city, along_curve=False)]
    assert not np.array_equal(graphs[0].forward.kept, graphs[1].forward.kept)
    n = city.network.n_nodes
    nodes = np.arange(n, dtype=np.int64)
    rng = np.random.default_rng(7)
    for s in rng.choice(n, 12, replace=False).tolist():
        seen = []
        for graph in graphs:
            g = graph.reverse if reverse else graph.forward
            costs = graph.time_reverse if reverse else graph.time_forward
            ws = heaps.workspace(graph, reverse)
            out = np.zeros(n, dtype=np.int64)
            unfolding.tree(g, graph.edges, costs, s, INF, NONE, nodes, ws, out)
            ties = [unfolding.resolve(g, graph.edges, costs, INF, v, ws)[1:3] for v in range(0, n, 7)]
            paths = [
                unfolding.path_to(graph.edges, g.towards, ws.pred, s, int(q)).tolist() for q in nodes[::97]
            ]
            seen.append((out.tolist(), ties, paths))
        assert seen[0] == seen[1]


def test_a_cycle_of_shape_nodes_only() -> None:
    # a two-way ring 0-1-2-3-4-0: every node is a chain interior; one is kept
    edges = {(i, (i + 1) % 5): 1.0 + i / 7 for i in range(5)} | {
        ((i + 1) % 5, i): 2.0 + i / 11 for i in range(5)
    }
    g = Graph(5, edges)
    g.pos = [(100.0 * np.cos(t), 100.0 * np.sin(t)) for t in np.arange(5) * 2 * np.pi / 5]
    c = contraction.contract(g.indptr, g.head)
    assert c.n_kept == 1 and c.n_super_edges == 2
    graph = as_road_graph(g)
    cost = (g.length * 1e6).astype(np.int64)
    everyone = np.arange(5, dtype=np.int64)
    for s in range(5):
        for reverse in (False, True):
            check(graph, cost, s, reverse, int(INF), NONE, everyone)


# ---------------------------------------------------------------- the search against the plain Dijkstra


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("reverse", [False, True])
def test_full_and_bounded_trees(seed: int, reverse: bool) -> None:
    g = chain_graph(seed)
    graph = as_road_graph(g)
    c = graph.reverse if reverse else graph.forward
    rng = np.random.default_rng(seed + 100)
    cost = (g.length * 1e6 * rng.uniform(0.3, 1.0, len(g.length))).astype(np.int64) + 1
    everyone = np.arange(g.n, dtype=np.int64)
    for s in interior_sources(c, rng, 5):
        check(graph, cost, s, reverse, int(INF), NONE, everyone)
        label, _ = canonical_tree(graph, cost, s, reverse)
        reach = [x[0] for x in label if x is not None]
        for limit in (int(np.median(reach)), int(rng.choice(reach)), 0):
            check(graph, cost, s, reverse, limit, NONE, everyone)


@pytest.mark.parametrize("seed", range(10))
def test_targets_and_queries(seed: int) -> None:
    g = chain_graph(seed)
    graph = as_road_graph(g)
    c = graph.forward
    rng = np.random.default_rng(seed + 200)
    cost = (g.length * 1e6 * rng.uniform(0.3, 1.0, len(g.length))).astype(np.int64) + 1
    for s in interior_sources(c, rng, 6):
        mates = chain_mates(c, s)  # the source's own chain(s): reached directly or around
        for targets in (
            rng.integers(g.n, size=int(rng.integers(1, 6))),
            np.array([s]),
            np.array(mates),
            np.array([*rng.integers(g.n, size=3), s, *mates]),
        ):
            targets = targets.astype(np.int64)
            check(graph, cost, s, False, int(INF), targets, targets)
        queries = rng.integers(g.n, size=10).astype(np.int64)  # the pickup search: a radius and the taxis
        check(graph, cost, s, False, int(np.median(cost)) * 6, queries, queries)


@pytest.mark.parametrize("seed", range(6))
def test_small_integer_costs_tie_everywhere(seed: int) -> None:
    """Costs of 1-3 microseconds: ties everywhere, decided by the tie words as the reference decides them."""
    g = chain_graph(seed)
    graph = as_road_graph(g)
    rng = np.random.default_rng(seed + 300)
    cost = rng.integers(1, 4, len(g.length)).astype(np.int64)
    everyone = np.arange(g.n, dtype=np.int64)
    for s in interior_sources(graph.forward, rng, 4):
        check(graph, cost, s, False, int(INF), NONE, everyone)
        check(graph, cost, s, True, int(INF), NONE, everyone)
        check(graph, cost, s, False, int(INF), everyone[:5], everyone)


_FIELDS = ("kept", "kept_of", "dead_end", "indptr", "se_tail", "se_head", "se_rev", "se_ptr", "se_edges")


def _same_contraction(indptr: np.ndarray, head: np.ndarray) -> None:
    got, want = contraction.contract(indptr, head), plain_contract(indptr, head)
    assert got.n_nodes == want.n_nodes
    for name in (*_FIELDS, "se_node", "pos_se", "pos_off"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name


@pytest.mark.parametrize("seed", range(12))
def test_the_compiled_contraction_is_the_plain_ones_array_for_array(seed: int) -> None:
    """Lattices with every kind of chain, forward and reversed: the compiled contraction gives exactly the
    arrays of the plain one written from the definition (``tests.reference_contraction``)."""
    g = chain_graph(seed, side=4 + seed % 4)
    _same_contraction(g.indptr, g.head)
    _same_contraction(g.reversed().indptr, g.reversed().head)


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_the_compiled_contraction_of_a_bundled_city_is_the_plain_ones(name: str) -> None:
    """The same on the bundled cities' road networks (OpenStreetMap's parallel ways, loops and one-way
    chains), forward and reversed."""
    from services.citydata import load_city

    net = load_city(BUNDLES / name).network
    head = np.asarray(net.edge_v, dtype=np.int64)
    _same_contraction(np.asarray(net.indptr, dtype=np.int64), head)
    tail = np.repeat(np.arange(net.n_nodes, dtype=np.int64), np.diff(net.indptr))
    rev_indptr = np.zeros(net.n_nodes + 1, dtype=np.int64)
    rev_indptr[1:] = np.cumsum(np.bincount(head, minlength=net.n_nodes))
    _same_contraction(rev_indptr, tail[np.lexsort((tail, head))])
