"""Slow, independent reference computations for the core: networkx paths, Python sensing sums,
brute force over every matching. Written from METHOD.md, sharing no code with services/ except the
grid's segment rule (``segment_cells``, itself tested against dense sampling)."""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Iterable, Sequence

import networkx as nx
import numpy as np

from services.city import City
from services.model import CountsView, IntervalKey, TaxiId
from services.sensing.grid import segment_cells


def nx_graph(city: City, weight: np.ndarray | None = None) -> nx.DiGraph:
    net = city.network
    g = nx.DiGraph()
    g.add_nodes_from(range(net.n_nodes))
    w = net.edge_time_s if weight is None else weight
    for e in range(net.n_edges):
        g.add_edge(int(net.edge_u[e]), int(net.edge_v[e]), w=float(w[e]), e=e)
    return g


def path_edges(g: nx.DiGraph, nodes: Sequence[int]) -> list[int]:
    return [g.edges[a, b]["e"] for a, b in itertools.pairwise(nodes)]


def crossings(city: City, edges: Iterable[int], depart_s: float) -> list[tuple[int, int, float]]:
    """(interval, cell, entry time) of every crossing of every edge, in travel order."""
    net = city.network
    out = []
    t = depart_s
    for e in edges:
        u, v = int(net.edge_u[e]), int(net.edge_v[e])
        cells, fracs = segment_cells(city.grid, net.x_m[u], net.y_m[u], net.x_m[v], net.y_m[v])
        for c, f in zip(cells, fracs, strict=True):
            entry = t + float(f) * float(net.edge_time_s[e])
            out.append((int(city.horizon.interval_of(entry)), int(c), entry))
        t += float(net.edge_time_s[e])
    return out


def gain(
    city: City,
    counts: CountsView,
    taxi: str | None,
    edges: Iterable[int],
    depart_s: float,
    extra: dict[tuple[int, int], int] | None = None,
) -> float:
    """Eq. (3) by the book: first entry per (interval, cell), skipping pairs the taxi is counted in."""
    seen: set[tuple[int, int]] = set()
    visited = counts.visited.get(TaxiId(taxi), frozenset()) if taxi else frozenset()
    total = 0.0
    rho = city.params.rho
    for k, c, _ in crossings(city, edges, depart_s):
        if (k, c) in seen:
            continue
        seen.add((k, c))
        if (k, c) in visited:
            continue
        arr = counts.counts.get(IntervalKey(k))
        lam = (int(arr[c]) if arr is not None else 0) + (extra or {}).get((k, c), 0)
        total += city.mu(k) * float(city.cell_weight[c]) * ((lam + 1) ** rho - lam**rho)
    return total


def fastest(g: nx.DiGraph, a: int, b: int) -> tuple[list[int], float]:
    length, nodes = nx.single_source_dijkstra(g, a, b, weight="w")
    return nodes, float(length)


def all_matchings(pairs: Sequence[tuple[int, int]]) -> Iterable[list[tuple[int, int]]]:
    """Every matching (as a list of pairs) drawn from ``pairs``."""
    pairs = list(pairs)

    def rec(k: int, rows: frozenset[int], cols: frozenset[int], cur: list[tuple[int, int]]):
        if k == len(pairs):
            yield list(cur)
            return
        yield from rec(k + 1, rows, cols, cur)
        i, j = pairs[k]
        if i not in rows and j not in cols:
            cur.append((i, j))
            yield from rec(k + 1, rows | {i}, cols | {j}, cur)
            cur.pop()

    yield from rec(0, frozenset(), frozenset(), [])


def lexi_best(pairs, primary, secondary, *, sense: str, tol: float = 1e-12):
    """Best (primary total, secondary total) over all matchings: max primary, then min/max secondary.
    Primary totals within ``tol`` (relative) count as equal."""
    best = None
    for mt in all_matchings(pairs):
        p = sum(primary[x] for x in mt)
        s = sum(secondary[x] for x in mt)
        if best is None:
            best = (p, s)
            continue
        bp, bs = best
        if (
            p > bp * (1 + tol) + 1e-15
            or abs(p - bp) <= tol * max(abs(bp), 1e-300) + 1e-15
            and ((sense == "min" and s < bs) or (sense == "max" and s > bs))
        ):
            best = (p, s)
    return best


def canonical_tree(graph, cost, source: int, reverse: bool = False):
    """(label per node, pred edge per node) of a plain lexicographic Dijkstra on the original edges:
    labels (cost, tie1, tie2) compared in order, so its tree is *the* canonical one of
    ``services.network.graph``."""
    ed = graph.edges
    n = graph.n_nodes
    adj: list[list[int]] = [[] for _ in range(n)]
    for e in range(graph.n_edges):
        adj[int(ed.head[e] if reverse else ed.tail[e])].append(e)
    label: list[tuple[int, int, int] | None] = [None] * n
    pred = [-1] * n
    label[source] = (0, 0, 0)
    heap = [(0, 0, 0, source)]
    done = [False] * n
    while heap:
        c, a, b, u = heapq.heappop(heap)
        if done[u] or (c, a, b) != label[u]:
            continue
        done[u] = True
        for e in adj[u]:
            v = int(ed.tail[e] if reverse else ed.head[e])
            new = (c + int(cost[e]), a + int(ed.tie1[e]), b + int(ed.tie2[e]))
            old = label[v]
            if old is None or new < old:
                label[v] = new
                pred[v] = e
                heapq.heappush(heap, (*new, v))
    return label, pred


def tree_path(graph, pred: list[int], source: int, v: int, reverse: bool = False) -> list[int]:
    """Edges of a tree path between ``source`` and ``v`` in travel order."""
    ed = graph.edges
    out = []
    while v != source:
        e = pred[v]
        out.append(e)
        v = int(ed.head[e] if reverse else ed.tail[e])
    return out if reverse else out[::-1]


def evaluate(graph, gn, zeroed: set[tuple[int, int]], edges: Sequence[int], depart_s: float):
    """(gain, time, length, largest slot) of a path by the book: first entry per (slot, cell), nothing
    where the taxi is counted, slots beyond the table gain nothing."""
    ed = graph.edges
    n_slots = gn.term.shape[0]
    seen: set[tuple[int, int]] = set()
    t, g, length, top = depart_s, 0.0, 0.0, 0
    for e in edges:
        te = float(ed.time_s[e])
        for j in range(int(ed.ec_ptr[e]), int(ed.ec_ptr[e + 1])):
            slot = math.floor((t + float(ed.ec_frac[j]) * te + gn.shift_s) / gn.interval_s) - gn.k0
            top = max(top, slot)
            c = int(ed.ec_cell[j])
            if slot >= n_slots or (slot, c) in seen:
                continue
            seen.add((slot, c))
            if (slot, c) not in zeroed:
                g += float(gn.term[slot, c])
        t += te
        length += float(ed.length_m[e])
    return g, t - depart_s, length, top


def kappa_cost(graph, gn, zeroed: set[tuple[int, int]], kappa: float):
    """Algorithm 1's edge costs for one taxi (microseconds), or None when every kappa is the fastest path."""
    ed = graph.edges
    if kappa == 0.0:
        return ed.time_us
    u = []
    for e in range(graph.n_edges):
        cells = ed.ec_cell[int(ed.ec_ptr[e]) + 1 : int(ed.ec_ptr[e + 1])]
        u.append(sum(float(gn.term[0, int(c)]) for c in cells if (0, int(c)) not in zeroed))
    umax = max(u, default=0.0)
    if umax <= 0.0:
        return None
    t = ed.time_s
    return [
        max(1, int(round(float(t[e]) * (1.0 - kappa * (u[e] / umax)) * 1e6))) for e in range(graph.n_edges)
    ]


def algorithm1(
    graph, gn, zeroed: set[tuple[int, int]], source: int, targets: Sequence[int], depart_s, kappas
):
    """Algorithm 1 by the book, one tree per kappa: per target (kappa, edges, gain, time, length), the
    largest phi, ties to the smaller kappa."""
    best: list[tuple[float, float, list[int], float, float, float] | None] = [None] * len(targets)
    for kappa in kappas:
        cost = kappa_cost(graph, gn, zeroed, kappa)
        if cost is None:
            continue
        label, pred = canonical_tree(graph, cost, source)
        for i, v in enumerate(targets):
            assert label[v] is not None, "unreachable target"
            edges = tree_path(graph, pred, source, int(v))
            g, t, length, _ = evaluate(graph, gn, zeroed, edges, depart_s)
            phi = g / t if t > 0 else 0.0
            cur = best[i]
            if cur is None or phi > cur[0]:
                best[i] = (phi, kappa, edges, g, t, length)
    return [(b[1], b[2], b[3], b[4], b[5]) for b in best if b is not None]


__all__ = [
    "canonical_tree",
    "tree_path",
    "evaluate",
    "kappa_cost",
    "algorithm1",
    "nx_graph",
    "path_edges",
    "crossings",
    "gain",
    "fastest",
    "all_matchings",
    "lexi_best",
]
