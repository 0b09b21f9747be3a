"""The road network in the forms the searches want: one :class:`RoadGraph` per city, built once.

A shortest path here is *canonical*: edge costs are whole microseconds (at least 1), and among paths of
equal cost the one with the smallest tie key wins, the tie key of a path being the sum of fixed
pseudo-random per-edge keys (two 47-bit words, compared in order). The minimum is then one path, whichever
way it is searched for: from the source, from the target, both ends at once, on the contracted graph or
on the original one. This is what lets Step 3 grow one fastest-path tree per POI instead of one per taxi
and lets point-to-point legs be searched from both ends, with every decision the same as the
straightforward one-search-per-taxi computation (``docs/DISPATCH.md``, "Canonical shortest paths").

:class:`SearchGraph` is one direction of the network with its chains of degree-2 nodes contracted
(``services.network.contraction``); :class:`Edges` holds the per-edge arrays. Both are ``NamedTuple`` s
of arrays so that the compiled kernels (``services.network.dijkstra``, ``services.sensing.gains``,
``services.routing.algorithm1``) take them as one typed argument each.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network.contraction import contract, hilbert_key, renumbered

if TYPE_CHECKING:
    from services.city import City

__all__ = [
    "Edges",
    "SearchGraph",
    "Costs",
    "Lazy",
    "no_lazy",
    "kappa_cost",
    "lazy_edge",
    "lazy_fill",
    "fixed_super_edges",
    "prepare",
    "prepare_into",
    "RoadGraph",
    "road_graph",
    "build_road_graph",
    "INF",
    "TIE_BITS",
    "US_PER_S",
    "to_us",
]

US_PER_S = 1_000_000
"""Search costs are whole microseconds."""

INF = 2**62
"""Cost of an unreached node."""

TIE_BITS = 47
"""Bits of each tie word: a path of up to 2**16 edges sums without overflow."""


class Edges(NamedTuple):
    """Per original edge (edge ``e`` runs ``tail[e] -> head[e]``)."""

    tail: NDArray[np.int64]
    head: NDArray[np.int64]
    time_s: NDArray[np.float64]
    length_m: NDArray[np.float64]
    time_us: NDArray[np.int64]  # the canonical travel-time cost, >= 1
    tie1: NDArray[np.int64]
    tie2: NDArray[np.int64]
    ec_ptr: NDArray[np.int64]  # cells crossed by edge e: ec_cell[ec_ptr[e]:ec_ptr[e+1]], in order,
    ec_cell: NDArray[np.int64]  # entered at fraction ec_frac[...] of the edge (the first at 0)
    ec_frac: NDArray[np.float64]


class SearchGraph(NamedTuple):
    """One direction of the network (forward, or reverse for in-trees) with degree-2 chains contracted.

    Kept node ``k`` (original node ``kept[k]``) leaves along super-edges ``indptr[k]:indptr[k+1]``;
    super-edge ``s`` runs ``se_tail[s] -> se_head[s]`` (kept indices) over the original edges
    ``se_edges[se_ptr[s]:se_ptr[s+1]]`` in travel order (original edge ids in both directions), the node
    after each being ``se_node``; ``se_rev[s]`` is the super-edge over the same interior nodes the other
    way (-1 if none). An interior node lies on ``pos_se[v, j]`` (j = 0, 1; -1 unused) with ``pos_off[v, j]``
    original edges before it. A ``dead_end`` kept node has a single neighbour. ``se_tie1/2`` are the
    super-edges' tie sums. ``towards`` is 1 for the forward graph (paths leave the source) and 0 for the
    reverse one (paths enter the root).
    """

    kept: NDArray[np.int64]
    kept_of: NDArray[np.int64]
    dead_end: NDArray[np.bool_]
    indptr: NDArray[np.int64]
    se_tail: NDArray[np.int64]
    se_head: NDArray[np.int64]
    se_rev: NDArray[np.int64]
    se_ptr: NDArray[np.int64]
    se_edges: NDArray[np.int64]
    se_node: NDArray[np.int64]
    pos_se: NDArray[np.int64]
    pos_off: NDArray[np.int64]
    se_tie1: NDArray[np.int64]
    se_tie2: NDArray[np.int64]
    towards: int


class Costs(NamedTuple):
    """A metric prepared for one search graph: per original edge (whole microseconds, >= 1), per super-edge
    (the sums), and the bucket queue's geometry (bucket width = the cheapest super-edge, so no node of a
    bucket can improve another node of the same bucket; ``span`` buckets cover the dearest super-edge)."""

    edge: NDArray[np.int64]
    se: NDArray[np.int64]
    width: int
    span: int


class Lazy(NamedTuple):
    """Algorithm 1's cost of one taxi, ``c_e = t_e (1 - kappa u_e / umax)`` (``kappa_cost``), computed as a
    search relaxes each super-edge instead of for every edge beforehand: ``u_e`` is the sum of ``term``
    over the cells edge ``e`` enters (all its cells but the first) that ``zmask`` leaves open, in the order
    the edge enters them (``lazy_edge``). A super-edge none of whose edges enters a cell costs its travel
    time under every such metric (``fixed``: that cost, -1 for the others). A search given one writes the
    costs of the super-edges a path may end or start inside (the source's and the targets'), and of their
    edges, into its ``Costs`` arrays beforehand, so ``unfolding.resolve`` finds them there.
    ``on`` False: the ``Costs`` arrays hold the metric already."""

    on: bool
    kappa: float
    umax: float
    term: NDArray[np.float64]  # (C,) the epoch's first slot's terms
    zmask: NDArray[np.bool_]  # (C,) True where the taxi is counted in the first slot
    fixed: NDArray[np.int64]  # (S,) a super-edge's cost if it enters no cell, else -1


@compiled
def no_lazy() -> Lazy:
    """The ``Lazy`` of a search whose ``Costs`` hold the metric."""
    return Lazy(
        False,
        0.0,
        1.0,
        np.zeros(0),
        np.zeros(0, dtype=np.bool_),
        np.zeros(0, dtype=np.int64),
    )


@compiled_inline
def kappa_cost(t: float, u: float, umax: float, kappa: float) -> int:
    """Algorithm 1's edge cost ``t (1 - kappa u / umax)`` in whole microseconds, at least 1 (kappa 0: the
    travel time)."""
    c = t * (1.0 - kappa * (u / umax)) if kappa != 0.0 else t
    q = int(np.rint(c * 1e6))
    return q if q > 1 else 1


@compiled_inline
def lazy_edge(edges: Edges, lazy: Lazy, e: int) -> int:
    """Edge ``e``'s cost under ``lazy``."""
    u = 0.0
    for j in range(edges.ec_ptr[e] + 1, edges.ec_ptr[e + 1]):
        c = edges.ec_cell[j]
        if not lazy.zmask[c]:
            u += lazy.term[c]
    return kappa_cost(edges.time_s[e], u, lazy.umax, lazy.kappa)


@compiled_inline
def lazy_fill(graph: SearchGraph, edges: Edges, costs: Costs, lazy: Lazy, s: int) -> None:
    """Write super-edge ``s``'s cost under ``lazy``, and its edges', into ``costs``."""
    total = 0
    for p in range(graph.se_ptr[s], graph.se_ptr[s + 1]):
        e = graph.se_edges[p]
        q = lazy_edge(edges, lazy, e)
        costs.edge[e] = q
        total += q
    costs.se[s] = total


@compiled
def prepare_into(graph: SearchGraph, edge_cost: NDArray[np.int64], se: NDArray[np.int64]) -> Costs:
    """``prepare`` writing the super-edge sums into ``se`` (length: the super-edges of ``graph``)."""
    ns = graph.se_tail.shape[0]
    lo = INF
    hi = 1
    for s in range(ns):
        c = 0
        for p in range(graph.se_ptr[s], graph.se_ptr[s + 1]):
            c += edge_cost[graph.se_edges[p]]
        se[s] = c
        if c < lo:
            lo = c
        if c > hi:
            hi = c
    if ns == 0:
        lo = 1
    return Costs(edge_cost, se, lo, hi // lo + 2)


def prepare(graph: SearchGraph, edge_cost: NDArray[np.int64]) -> Costs:
    """The metric ``edge_cost`` (whole microseconds, >= 1 each) prepared for searches on ``graph``."""
    costs: Costs = prepare_into(graph, edge_cost, np.empty(graph.se_tail.shape[0], dtype=np.int64))
    return costs


@dataclass(frozen=True, slots=True, eq=False, weakref_slot=True)
class RoadGraph:
    """A city's network for searching: the edges, the forward and the reverse search graphs."""

    n_nodes: int
    n_cells: int
    edges: Edges
    forward: SearchGraph
    reverse: SearchGraph
    time_forward: Costs  # the travel time, prepared for ``forward``
    time_reverse: Costs
    crossing: NDArray[np.int64]  # the edges that enter a cell (all but their first): ascending
    min_speed_mps: float

    @property
    def n_edges(self) -> int:
        return int(self.edges.tail.shape[0])


def to_us(seconds: NDArray[np.float64]) -> NDArray[np.int64]:
    """Seconds to whole microseconds, at least 1 (search costs must be positive)."""
    return np.maximum(np.rint(np.asarray(seconds, dtype=np.float64) * US_PER_S), 1).astype(np.int64)


def _tie_words(m: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Two fixed pseudo-random words per edge index (splitmix64 of the index; the same for every run)."""
    mask = np.uint64((1 << 64) - 1)

    def splitmix(x: NDArray[np.uint64]) -> NDArray[np.uint64]:
        with np.errstate(over="ignore"):
            z = (x + np.uint64(0x9E3779B97F4A7C15)) & mask
            z = ((z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & mask
            z = ((z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & mask
            return z ^ (z >> np.uint64(31))

    idx = np.arange(m, dtype=np.uint64)
    keep = np.uint64((1 << TIE_BITS) - 1)
    a = splitmix(idx * np.uint64(2)) & keep
    b = splitmix(idx * np.uint64(2) + np.uint64(1)) & keep
    return a.astype(np.int64), b.astype(np.int64)


def _search_graph(
    indptr: NDArray[np.int64],
    head: NDArray[np.int64],
    edge_id: NDArray[np.int64],
    tie1: NDArray[np.int64],
    tie2: NDArray[np.int64],
    towards: int,
    xy: tuple[NDArray[np.float64], NDArray[np.float64]] | None,
) -> SearchGraph:
    """One direction's search graph, its kept nodes numbered along a Hilbert curve over their positions
    ``xy`` (``contraction.renumbered``: the same graph, laid out so that a search's nodes lie together;
    None: in the order of the network's nodes)."""
    c = contract(indptr, head)
    if xy is not None:
        c = renumbered(c, np.argsort(hilbert_key(xy[0][c.kept], xy[1][c.kept]), kind="stable"))
    se_edges = edge_id[c.se_edges]  # CSR slots -> original edge ids
    g = SearchGraph(
        kept=c.kept,
        kept_of=c.kept_of,
        dead_end=c.dead_end,
        indptr=c.indptr,
        se_tail=c.se_tail,
        se_head=c.se_head,
        se_rev=c.se_rev,
        se_ptr=c.se_ptr,
        se_edges=se_edges.astype(np.int64),
        se_node=c.se_node.astype(np.int64),
        pos_se=c.pos_se,
        pos_off=c.pos_off,
        se_tie1=np.zeros(0, dtype=np.int64),
        se_tie2=np.zeros(0, dtype=np.int64),
        towards=towards,
    )
    return g._replace(se_tie1=_sum_over_super_edges(g, tie1), se_tie2=_sum_over_super_edges(g, tie2))


def _sum_over_super_edges(graph: SearchGraph, per_edge: NDArray[np.int64]) -> NDArray[np.int64]:
    if graph.se_ptr.shape[0] <= 1:
        return np.zeros(0, dtype=np.int64)
    return np.add.reduceat(per_edge[graph.se_edges], graph.se_ptr[:-1]).astype(np.int64)


@functools.lru_cache(maxsize=16)
def road_graph(city: City) -> RoadGraph:
    """Build (once per city) the edges and the contracted forward and reverse search graphs."""
    return build_road_graph(city)


def build_road_graph(city: City, *, along_curve: bool = True) -> RoadGraph:
    """``road_graph`` uncached; ``along_curve`` False keeps the kept nodes in the order of the network's
    nodes instead of numbering them along a Hilbert curve (the same searches, slower where the network's
    order is not its geography's: the benchmarks compare the two)."""
    net = city.network
    xy = (net.x_m, net.y_m) if along_curve else None
    m = net.n_edges
    tail = net.edge_u.astype(np.int64)
    head = net.edge_v.astype(np.int64)
    tie1, tie2 = _tie_words(m)
    forward = _search_graph(
        net.indptr.astype(np.int64), head, np.arange(m, dtype=np.int64), tie1, tie2, 1, xy
    )
    order = np.lexsort((tail, head)).astype(np.int64)  # in-edges grouped by head: the reverse CSR
    rev_indptr = np.zeros(net.n_nodes + 1, dtype=np.int64)
    np.add.at(rev_indptr, head + 1, 1)
    reverse = _search_graph(np.cumsum(rev_indptr), tail[order], order, tie1, tie2, 0, xy)
    if not np.array_equal(forward.kept, reverse.kept):  # a chain interior has one way in and one out
        raise AssertionError("the forward and reverse search graphs keep different nodes")
    speed = net.edge_length_m / np.maximum(net.edge_time_s, 1e-12)
    positive = speed[speed > 0]
    edges = Edges(
        tail=tail,
        head=head,
        time_s=net.edge_time_s.astype(np.float64),
        length_m=net.edge_length_m.astype(np.float64),
        time_us=to_us(net.edge_time_s),
        tie1=tie1,
        tie2=tie2,
        ec_ptr=city.edge_cells.ptr.astype(np.int64),
        ec_cell=city.edge_cells.cell.astype(np.int64),
        ec_frac=city.edge_cells.frac.astype(np.float64),
    )
    return RoadGraph(
        n_nodes=net.n_nodes,
        n_cells=city.grid.n_cells,
        edges=edges,
        forward=forward,
        reverse=reverse,
        time_forward=prepare(forward, edges.time_us),
        time_reverse=prepare(reverse, edges.time_us),
        crossing=np.flatnonzero(np.diff(edges.ec_ptr) > 1).astype(np.int64),
        min_speed_mps=float(positive.min()) if positive.size else 1.0,
    )


def fixed_super_edges(graph: SearchGraph, edges: Edges, time: Costs) -> NDArray[np.int64]:
    """Per super-edge of ``graph``: its travel time (``time``, prepared for ``graph``) if none of its edges
    enters a cell, so that its cost is that under every kappa metric, else -1 (``Lazy.fixed``)."""
    if graph.se_ptr.shape[0] <= 1:
        return np.zeros(0, dtype=np.int64)
    crossing = (np.diff(edges.ec_ptr) > 1)[graph.se_edges]
    return np.where(np.logical_or.reduceat(crossing, graph.se_ptr[:-1]), -1, time.se).astype(np.int64)
