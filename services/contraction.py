"""Shortest paths on a network whose chains of degree-2 nodes are contracted into super-edges.

OSM networks are mostly shape points: nodes with one way in and one way out. Searching only the *kept*
nodes (junctions, dead ends, one node of any cycle made of shape points alone) settles a fraction of the
nodes; the interior nodes of a chain are read off its ends afterwards. Every super-edge keeps its original
edges in travel order and its cost is folded edge by edge from the tail's distance, so distances, paths,
times and cell crossings are those of the original network (bit-identical distances; identical paths
unless two paths tie exactly).

A node ``v`` is a chain *interior* if it has exactly one in-edge and one out-edge, from and to different
neighbours (one-way chain), or exactly two neighbours ``a != b`` with edges ``a->v, v->b, b->v, v->a``
(two-way chain). Every other node is kept. A maximal run of interiors between kept nodes becomes one
super-edge per direction; a two-way chain's two super-edges are each other's ``rev``.

:func:`dijkstra` is the entry point: it has the arguments and results of :func:`services.kernels.dijkstra`
(plus the nodes whose values are wanted) and uses the contracted graph when :data:`ENABLED` is set.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from services import kernels

if TYPE_CHECKING:
    from services.routing import GraphArrays

__all__ = ["ENABLED", "Contraction", "contract", "forward", "reverse", "dijkstra"]

ENABLED = True
"""Search the contracted graph (True) or the original one with ``kernels.dijkstra`` (the reference)."""


@dataclass(frozen=True, slots=True, eq=False)
class Contraction:
    """A CSR graph with its degree-2 chains contracted (all indices int64).

    Attributes
    ----------
    n_nodes : int
        Nodes of the original graph.
    kept : (K,)
        Original node of each kept node.
    kept_of : (n,)
        Kept index of each original node, -1 for chain interiors.
    dead_end : (K,) bool
        Kept nodes with a single neighbour (one edge in from it, one out to it): no shortest path passes
        through them, so the search settles them when reached instead of queueing them.
    indptr : (K+1,)
        Super-edges leaving kept node ``k``: ``indptr[k]:indptr[k+1]`` (ordered by their first edge).
    se_tail, se_head : (S,)
        Kept indices at the ends of each super-edge.
    se_rev : (S,)
        The super-edge over the same interior nodes in the other direction, -1 if none.
    se_ptr : (S+1,)
        Super-edge ``s`` is the original edges ``se_edges[se_ptr[s]:se_ptr[s+1]]``.
    se_edges : (m,)
        Original edge ids, in travel order along each super-edge; every edge appears exactly once.
    se_node : (m,)
        The node each of those edges enters.
    pos_se, pos_off : (n, 2)
        The super-edges an interior node lies on (ascending, -1 unused) and how many of their edges come
        before it (1 .. len - 1).
    """

    n_nodes: int
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

    @property
    def n_kept(self) -> int:
        """Kept nodes (the nodes the search settles)."""
        return int(self.kept.shape[0])

    @property
    def n_super_edges(self) -> int:
        """Edges of the contracted graph."""
        return int(self.se_tail.shape[0])

    @property
    def arrays(self) -> tuple[NDArray[Any], ...]:
        """The graph's arrays in the order ``kernels.dijkstra_contracted`` and ``plan_kappas`` take them."""
        return (
            self.indptr,
            self.se_head,
            self.se_tail,
            self.se_rev,
            self.se_ptr,
            self.se_edges,
            self.se_node,
            self.kept,
            self.kept_of,
            self.dead_end,
            self.pos_se,
            self.pos_off,
        )


def _interiors(
    indptr: NDArray[np.int64], head: NDArray[np.int64], tail: NDArray[np.int64]
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Which nodes are chain interiors (one-way or two-way, before breaking pure chain cycles), and which
    are dead ends (a single neighbour, joined both ways)."""
    n = indptr.shape[0] - 1
    outdeg = np.diff(indptr)
    indeg = np.bincount(head, minlength=n)
    in_order = np.argsort(head, kind="stable")
    in_ptr = np.zeros(n + 1, dtype=np.int64)
    in_ptr[1:] = np.cumsum(indeg)
    interior = np.zeros(n, dtype=bool)
    dead_end = np.zeros(n, dtype=bool)
    for v in np.flatnonzero((indeg == outdeg) & ((indeg == 1) | (indeg == 2))).tolist():
        outs = set(head[indptr[v] : indptr[v + 1]].tolist())
        ins = set(tail[in_order[in_ptr[v] : in_ptr[v + 1]]].tolist())
        if len(outs) != outdeg[v] or v in outs:  # parallel edges or self-loops: keep the node
            continue
        interior[v] = (outs != ins) if indeg[v] == 1 else (outs == ins)
        dead_end[v] = indeg[v] == 1 and outs == ins
    return interior, dead_end


def contract(indptr: NDArray[np.int64], head: NDArray[np.integer]) -> Contraction:
    """Contract the degree-2 chains of the CSR graph ``(indptr, head)``.

    Parameters
    ----------
    indptr : (n+1,) int
        Out-edges of node ``u`` are edges ``indptr[u]:indptr[u+1]``.
    head : (m,) int
        Head node of each edge.

    Returns
    -------
    Contraction
        Kept nodes, super-edges and the position of every interior node.
    """
    indptr = np.asarray(indptr, dtype=np.int64)
    head64 = np.asarray(head, dtype=np.int64)
    n = int(indptr.shape[0] - 1)
    m = int(head64.shape[0])
    tail = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    interior, dead_end = _interiors(indptr, head64, tail)
    ip = indptr.tolist()
    hd = head64.tolist()
    edge_se = [-1] * m
    chains: list[list[int]] = []

    def walk(e: int) -> None:
        prev, x = int(tail[e]), hd[e]
        edges = [e]
        edge_se[e] = len(chains)
        while interior[x]:
            f = next(f for f in range(ip[x], ip[x + 1]) if hd[f] != prev)
            edges.append(f)
            edge_se[f] = len(chains)
            prev, x = x, hd[f]
        chains.append(edges)

    for u in np.flatnonzero(~interior).tolist():
        for e in range(ip[u], ip[u + 1]):
            walk(e)
    for e in range(m):  # edges still free lie on cycles of interiors only: keep one node of each
        if edge_se[e] < 0:
            u = int(tail[e])
            interior[u] = False
            for f in range(ip[u], ip[u + 1]):
                walk(f)

    order = sorted(range(len(chains)), key=lambda s: chains[s][0])  # by first edge = by tail, CSR order
    chains = [chains[s] for s in order]
    n_se = len(chains)
    kept = np.flatnonzero(~interior).astype(np.int64)
    kept_of = np.full(n, -1, dtype=np.int64)
    kept_of[kept] = np.arange(kept.shape[0], dtype=np.int64)
    se_ptr = np.zeros(n_se + 1, dtype=np.int64)
    se_ptr[1:] = np.cumsum([len(c) for c in chains])
    se_edges = np.array([e for c in chains for e in c], dtype=np.int64)
    se_tail = kept_of[tail[se_edges[se_ptr[:-1]]]] if n_se else np.zeros(0, dtype=np.int64)
    se_head = kept_of[head64[se_edges[se_ptr[1:] - 1]]] if n_se else np.zeros(0, dtype=np.int64)
    k_indptr = np.zeros(kept.shape[0] + 1, dtype=np.int64)
    np.add.at(k_indptr, se_tail + 1, 1)
    k_indptr = np.cumsum(k_indptr)

    first_of = {c[0]: s for s, c in enumerate(chains)}
    edge_id = {(int(tail[e]), hd[e]): e for e in range(m)}
    se_rev = np.full(n_se, -1, dtype=np.int64)
    pos: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for s, c in enumerate(chains):
        if len(c) < 2:
            continue
        for off in range(1, len(c)):
            pos[hd[c[off - 1]]].append((s, off))
        last = c[-1]
        back = edge_id.get((hd[last], int(tail[last])))
        if back is not None and back in first_of and len(chains[first_of[back]]) == len(c):
            r = first_of[back]
            if [hd[e] for e in chains[r][:-1]] == [hd[e] for e in reversed(c[:-1])]:
                se_rev[s] = r
    pos_se = np.full((n, 2), -1, dtype=np.int64)
    pos_off = np.zeros((n, 2), dtype=np.int64)
    for v in np.flatnonzero(interior).tolist():
        ps = sorted(pos[v])
        if not 1 <= len(ps) <= 2:
            raise AssertionError(f"interior node {v} lies on {len(ps)} super-edges")
        for j, (s, off) in enumerate(ps):
            pos_se[v, j] = s
            pos_off[v, j] = off
    return Contraction(
        n_nodes=n,
        kept=kept,
        kept_of=kept_of,
        dead_end=dead_end[kept],
        indptr=k_indptr,
        se_tail=se_tail.astype(np.int64),
        se_head=se_head.astype(np.int64),
        se_rev=se_rev,
        se_ptr=se_ptr,
        se_edges=se_edges,
        se_node=head64[se_edges],
        pos_se=pos_se,
        pos_off=pos_off,
    )


@functools.lru_cache(maxsize=16)
def forward(ga: GraphArrays) -> Contraction:
    """The contraction of a city's forward CSR (``ga.indptr``, ``ga.head``), built once."""
    return contract(ga.indptr, ga.head)


@functools.lru_cache(maxsize=16)
def reverse(ga: GraphArrays) -> Contraction:
    """The contraction of a city's reverse CSR (``ga.rev_indptr``, ``ga.rev_head``), built once."""
    return contract(ga.rev_indptr, ga.rev_head)


def search(
    c: Contraction,
    cost: NDArray[np.float64],
    source: int,
    limit: float,
    targets: NDArray[np.int64],
    aux: NDArray[np.float64],
    queries: NDArray[np.int64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """``kernels.dijkstra`` on the contracted graph ``c`` (see ``kernels.dijkstra_contracted``).

    Parameters
    ----------
    c : Contraction
        The contracted graph of the CSR that ``cost`` and ``aux`` (per original edge) belong to.
    cost, aux : (m,) float64
        Edge costs (non-negative) and the weights summed along each tree path.
    source : int
        Root node.
    limit : float
        Nodes farther than ``limit`` are not settled.
    targets : (k,) int64
        Stop once these are settled (all nodes when empty).
    queries : (q,) int64, optional
        Nodes whose values (and tree paths) are wanted; ``targets`` when omitted.

    Returns
    -------
    dist, pred_edge, aux_sum
        As ``kernels.dijkstra``, written for the source, the settled kept nodes, the queries and the nodes
        on their tree paths.
    """
    q = targets if queries is None else np.asarray(queries, dtype=np.int64)
    result: tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]] = kernels.dijkstra_contracted(
        *c.arrays,
        cost,
        aux,
        int(source),
        float(limit),
        np.asarray(targets, dtype=np.int64),
        q,
    )
    return result


def dijkstra(
    ga: GraphArrays,
    cost: NDArray[np.float64],
    source: int,
    limit: float,
    targets: NDArray[np.int64],
    aux: NDArray[np.float64],
    *,
    reverse_graph: bool = False,
    queries: NDArray[np.int64] | None = None,
    contracted: bool | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """One shortest-path search on a city's forward (or reverse) CSR, contracted when :data:`ENABLED`.

    Parameters
    ----------
    ga : GraphArrays
        The city's arrays; ``cost`` and ``aux`` are indexed like ``ga.head`` (``ga.rev_head`` when
        ``reverse_graph``), and ``pred_edge`` holds edge ids of that CSR.
    cost, source, limit, targets, aux
        As ``kernels.dijkstra``.
    reverse_graph : bool
        Search the reverse CSR (an in-tree toward ``source``).
    queries : (q,) int64, optional
        Nodes whose values are read afterwards (``targets`` when omitted). The contracted search writes
        values only for these, the source, the kept nodes it settles and the nodes on their tree paths;
        the plain search writes every settled node.
    contracted : bool, optional
        Override :data:`ENABLED` for this call.

    Returns
    -------
    dist, pred_edge, aux_sum
        As ``kernels.dijkstra``.
    """
    use = ENABLED if contracted is None else contracted
    if use:
        c = reverse(ga) if reverse_graph else forward(ga)
        return search(c, cost, source, limit, targets, aux, queries)
    indptr, head = (ga.rev_indptr, ga.rev_head) if reverse_graph else (ga.indptr, ga.head)
    result: tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]] = kernels.dijkstra(
        indptr, head, cost, int(source), float(limit), np.asarray(targets, dtype=np.int64), aux
    )
    return result
