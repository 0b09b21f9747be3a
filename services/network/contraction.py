"""A network's chains of degree-2 nodes contracted into super-edges (built once per city by ``graph``).

OSM networks are mostly shape points: nodes with one way in and one way out. Searching only the *kept*
nodes (junctions, dead ends, one node of any cycle made of shape points alone) settles a fraction of the
nodes; the interior nodes of a chain are read off its ends afterwards (``services.network.unfolding``). Every
super-edge keeps its original edges in travel order, so costs, paths, times and cell crossings are those
of the original network.

A node ``v`` is a chain *interior* if it has exactly one in-edge and one out-edge, from and to different
neighbours (one-way chain), or exactly two neighbours ``a != b`` with edges ``a->v, v->b, b->v, v->a``
(two-way chain). Every other node is kept. A maximal run of interiors between kept nodes becomes one
super-edge per direction; a two-way chain's two super-edges are each other's ``rev``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Contraction", "contract"]


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


def _chains(
    ip: list[int], hd: list[int], tail: NDArray[np.int64], interior: NDArray[np.bool_]
) -> list[list[int]]:
    """The edges of every chain, walked from each kept node's out-edges; edges left over lie on cycles of
    interior nodes only, and one node of each such cycle is kept (``interior`` is updated)."""
    m = len(hd)
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
    return chains


def _positions(
    chains: list[list[int]], hd: list[int], tail: NDArray[np.int64], interior: NDArray[np.bool_]
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Each chain's reverse chain (-1 none) and each interior node's (chain, offset) on at most two chains."""
    n, m, n_se = len(interior), len(hd), len(chains)
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
    return se_rev, pos_se, pos_off


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
    tail = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    interior, dead_end = _interiors(indptr, head64, tail)
    ip = indptr.tolist()
    hd = head64.tolist()
    chains = _chains(ip, hd, tail, interior)
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

    se_rev, pos_se, pos_off = _positions(chains, hd, tail, interior)
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
