"""Slow, independent reference computations for the core: networkx paths, Python sensing sums,
brute force over every matching. Written from METHOD.md, sharing no code with services/ except the
grid's segment rule (``segment_cells``, itself tested against dense sampling)."""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence

import networkx as nx
import numpy as np

from services.city import City
from services.grid import segment_cells
from services.model import CountsView


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
    visited = counts.visited.get(taxi, frozenset()) if taxi else frozenset()
    total = 0.0
    rho = city.params.rho
    for k, c, _ in crossings(city, edges, depart_s):
        if (k, c) in seen:
            continue
        seen.add((k, c))
        if (k, c) in visited:
            continue
        arr = counts.counts.get(k)
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


__all__ = [
    "nx_graph",
    "path_edges",
    "crossings",
    "gain",
    "fastest",
    "all_matchings",
    "lexi_best",
]
