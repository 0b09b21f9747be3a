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

from services.kernel.jit import compiled

__all__ = ["Contraction", "contract", "hilbert_key", "renumbered"]


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
    indeg = np.bincount(head, minlength=n)
    in_ptr = np.zeros(n + 1, dtype=np.int64)
    in_ptr[1:] = np.cumsum(indeg)
    in_tail = tail[np.argsort(head, kind="stable")]
    return _classify(indptr, head, in_ptr, in_tail)


@compiled
def _classify(
    indptr: NDArray[np.int64], head: NDArray[np.int64], in_ptr: NDArray[np.int64], in_tail: NDArray[np.int64]
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """``_interiors`` from the out-edges' heads and the in-edges' tails of every node: a node with one edge
    in and one out is an interior unless both join the same neighbour (a dead end); one with two in and
    two out, when both go to and come from the same two other nodes; a parallel edge or a self-loop keeps
    a node."""
    n = indptr.shape[0] - 1
    interior = np.zeros(n, dtype=np.bool_)
    dead_end = np.zeros(n, dtype=np.bool_)
    for v in range(n):
        k = indptr[v + 1] - indptr[v]
        if k != in_ptr[v + 1] - in_ptr[v] or not 1 <= k <= 2:
            continue
        o0, o1 = head[indptr[v]], head[indptr[v + 1] - 1]
        i0, i1 = in_tail[in_ptr[v]], in_tail[in_ptr[v + 1] - 1]
        if (k == 2 and o0 == o1) or o0 == v or o1 == v:  # parallel edges or self-loops: keep the node
            continue
        if k == 1:
            interior[v] = o0 != i0
            dead_end[v] = o0 == i0
        else:
            interior[v] = i0 != i1 and ((o0 == i0 and o1 == i1) or (o0 == i1 and o1 == i0))
    return interior, dead_end


@compiled
def _walk(
    ip: NDArray[np.int64],
    hd: NDArray[np.int64],
    tail: NDArray[np.int64],
    interior: NDArray[np.bool_],
    e: int,
    flat: NDArray[np.int64],
    n_flat: int,
) -> int:
    """The chain that starts with edge ``e``, appended to ``flat`` from ``n_flat`` on: through each interior
    node, its out-edge that does not go back. Returns where the chain ends in ``flat``."""
    prev, x = tail[e], hd[e]
    flat[n_flat] = e
    n_flat += 1
    while interior[x]:
        f = ip[x]
        while hd[f] == prev:
            f += 1
        flat[n_flat] = f
        n_flat += 1
        prev, x = x, hd[f]
    return n_flat


@compiled
def _chains(
    ip: NDArray[np.int64], hd: NDArray[np.int64], tail: NDArray[np.int64], interior: NDArray[np.bool_]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The edges of every chain (``flat[ptr[s]:ptr[s + 1]]``), walked from each kept node's out-edges; edges
    left over lie on cycles of interior nodes only, and one node of each such cycle is kept (``interior``
    is updated)."""
    n, m = interior.shape[0], hd.shape[0]
    flat = np.empty(m, dtype=np.int64)
    ptr = np.zeros(m + 1, dtype=np.int64)
    on_chain = np.zeros(m, dtype=np.bool_)
    n_se = 0
    n_flat = 0
    for u in range(n):
        if interior[u]:
            continue
        for e in range(ip[u], ip[u + 1]):
            n_flat = _walk(ip, hd, tail, interior, e, flat, n_flat)
            n_se += 1
            ptr[n_se] = n_flat
    for j in range(n_flat):
        on_chain[flat[j]] = True
    for e in range(m):  # edges still free lie on cycles of interiors only: keep one node of each
        if not on_chain[e]:
            u = tail[e]
            interior[u] = False
            for f in range(ip[u], ip[u + 1]):
                start = n_flat
                n_flat = _walk(ip, hd, tail, interior, f, flat, n_flat)
                n_se += 1
                ptr[n_se] = n_flat
                for j in range(start, n_flat):
                    on_chain[flat[j]] = True
    return flat, ptr[: n_se + 1].copy()


@compiled
def _reverse_of(
    ip: NDArray[np.int64],
    hd: NDArray[np.int64],
    tail: NDArray[np.int64],
    flat: NDArray[np.int64],
    ptr: NDArray[np.int64],
    first_of: NDArray[np.int64],
    s: int,
) -> int:
    """The chain over the same interior nodes as chain ``s`` in the other direction, -1 if none: the one
    whose first edge is the last (in edge order) from ``s``'s head back to its last interior node."""
    last = flat[ptr[s + 1] - 1]
    u, w = hd[last], tail[last]
    back = -1
    for f in range(ip[u], ip[u + 1]):
        if hd[f] == w:
            back = f
    if back < 0 or first_of[back] < 0:
        return -1
    r = int(first_of[back])
    k = ptr[s + 1] - ptr[s]
    if ptr[r + 1] - ptr[r] != k:
        return -1
    for j in range(k - 1):  # r's interior nodes are s's, in reverse
        if hd[flat[ptr[r] + j]] != hd[flat[ptr[s + 1] - 2 - j]]:
            return -1
    return r


@compiled
def _positions(
    ip: NDArray[np.int64],
    hd: NDArray[np.int64],
    tail: NDArray[np.int64],
    flat: NDArray[np.int64],
    ptr: NDArray[np.int64],
    interior: NDArray[np.bool_],
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], int]:
    """Each chain's reverse chain (-1 none) and each interior node's (chain, offset) on at most two chains,
    ascending; and an interior node on no chain or on more than two (-1: none)."""
    n, n_se = interior.shape[0], ptr.shape[0] - 1
    first_of = np.full(hd.shape[0], -1, dtype=np.int64)
    for s in range(n_se):
        first_of[flat[ptr[s]]] = s
    se_rev = np.full(n_se, -1, dtype=np.int64)
    pos_se = np.full((n, 2), -1, dtype=np.int64)
    pos_off = np.zeros((n, 2), dtype=np.int64)
    count = np.zeros(n, dtype=np.int64)
    for s in range(n_se):
        if ptr[s + 1] - ptr[s] < 2:
            continue
        for off in range(1, ptr[s + 1] - ptr[s]):
            v = hd[flat[ptr[s] + off - 1]]
            if count[v] < 2:
                pos_se[v, count[v]] = s
                pos_off[v, count[v]] = off
            count[v] += 1
        se_rev[s] = _reverse_of(ip, hd, tail, flat, ptr, first_of, s)
    for v in range(n):  # the chains are met in order, each from its start: (chain, offset) ascend
        if interior[v] and not 1 <= count[v] <= 2:
            return se_rev, pos_se, pos_off, v
    return se_rev, pos_se, pos_off, -1


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
    flat, ptr = _chains(indptr, head64, tail, interior)
    order = np.argsort(flat[ptr[:-1]])  # by first edge = by tail, CSR order
    lengths = np.diff(ptr)[order]
    n_se = int(order.shape[0])
    se_ptr = np.zeros(n_se + 1, dtype=np.int64)
    se_ptr[1:] = np.cumsum(lengths)
    # the chains' blocks of ``flat`` in that order: each edge's place in its chain plus its chain's start
    se_edges = flat[np.repeat(ptr[order] - se_ptr[:-1], lengths) + np.arange(flat.shape[0])]
    kept = np.flatnonzero(~interior).astype(np.int64)
    kept_of = np.full(n, -1, dtype=np.int64)
    kept_of[kept] = np.arange(kept.shape[0], dtype=np.int64)
    se_tail = kept_of[tail[se_edges[se_ptr[:-1]]]] if n_se else np.zeros(0, dtype=np.int64)
    se_head = kept_of[head64[se_edges[se_ptr[1:] - 1]]] if n_se else np.zeros(0, dtype=np.int64)
    k_indptr = np.zeros(kept.shape[0] + 1, dtype=np.int64)
    np.add.at(k_indptr, se_tail + 1, 1)
    k_indptr = np.cumsum(k_indptr)

    se_rev, pos_se, pos_off, stray = _positions(indptr, head64, tail, se_edges, se_ptr, interior)
    if stray >= 0:
        raise AssertionError(f"interior node {stray} lies on none or more than two super-edges")
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


HILBERT_BITS = 16
"""``hilbert_key`` places positions on a 2**16 x 2**16 lattice over their bounding box."""


def hilbert_key(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.int64]:
    """Each position's index along a Hilbert curve over the bounding box of ``(x, y)``: positions near each
    other on the ground mostly get keys near each other."""
    n = 1 << HILBERT_BITS
    xs, ys = (np.asarray(a, dtype=np.float64) for a in (x, y))
    if xs.size == 0:
        return np.zeros(0, dtype=np.int64)

    def lattice(a: NDArray[np.float64]) -> NDArray[np.int64]:
        scaled: NDArray[np.float64] = (a - a.min()) / max(float(np.ptp(a)), 1e-9) * (n - 1)
        return scaled.astype(np.int64)

    xi, yi = lattice(xs), lattice(ys)
    key = np.zeros(xs.shape[0], dtype=np.int64)
    s = n >> 1
    while s > 0:
        rx = (xi & s) > 0
        ry = (yi & s) > 0
        key += s * s * ((3 * rx.astype(np.int64)) ^ ry.astype(np.int64))
        flip = ~ry & rx  # rotate the quadrant so that the curve's pieces join
        xi = np.where(flip, s - 1 - xi, xi)
        yi = np.where(flip, s - 1 - yi, yi)
        xi, yi = np.where(ry, xi, yi), np.where(ry, yi, xi)
        s >>= 1
    return key


def renumbered(c: Contraction, order: NDArray[np.int64]) -> Contraction:
    """``c`` with its kept nodes renumbered: new kept node ``i`` is old kept node ``order[i]`` (a
    permutation). Super-edges follow in CSR order of their new tails, each tail's in the order they had (by
    first edge); every path, cost and interior position is the same, only the indices change.

    A search touches the arrays of the kept nodes near the ones it settles: numbered along a Hilbert curve
    (``hilbert_key`` of their positions) those lie near each other in memory whatever order the network's
    nodes came in (an OpenStreetMap extract numbers them by when they were mapped)."""
    k = c.kept.shape[0]
    order = np.asarray(order, dtype=np.int64)
    if order.shape != (k,) or not np.array_equal(np.sort(order), np.arange(k)):
        raise ValueError("order must be a permutation of the kept nodes")
    new_of = np.empty(k, dtype=np.int64)
    new_of[order] = np.arange(k, dtype=np.int64)
    se_order = np.argsort(new_of[c.se_tail], kind="stable").astype(np.int64)
    n_se = se_order.shape[0]
    se_new = np.empty(n_se, dtype=np.int64)
    se_new[se_order] = np.arange(n_se, dtype=np.int64)
    lengths = np.diff(c.se_ptr)[se_order]
    se_ptr = np.zeros(n_se + 1, dtype=np.int64)
    se_ptr[1:] = np.cumsum(lengths)
    take = np.repeat(c.se_ptr[:-1][se_order] - se_ptr[:-1], lengths) + np.arange(se_ptr[-1])
    se_tail = new_of[c.se_tail[se_order]]
    indptr = np.zeros(k + 1, dtype=np.int64)
    indptr[1:] = np.cumsum(np.bincount(se_tail, minlength=k))
    rev = c.se_rev[se_order]
    pos_se = np.where(c.pos_se >= 0, se_new[np.maximum(c.pos_se, 0)], -1)
    pos_off = c.pos_off.copy()
    swap = (pos_se[:, 1] >= 0) & (pos_se[:, 1] < pos_se[:, 0])  # keep each node's two ascending
    pos_se[swap] = pos_se[swap][:, ::-1]
    pos_off[swap] = pos_off[swap][:, ::-1]
    kept_of = c.kept_of.copy()
    kept_of[c.kept[order]] = np.arange(k, dtype=np.int64)
    return Contraction(
        n_nodes=c.n_nodes,
        kept=c.kept[order],
        kept_of=kept_of,
        dead_end=c.dead_end[order],
        indptr=indptr,
        se_tail=se_tail,
        se_head=new_of[c.se_head[se_order]],
        se_rev=np.where(rev >= 0, se_new[np.maximum(rev, 0)], -1),
        se_ptr=se_ptr,
        se_edges=c.se_edges[take],
        se_node=c.se_node[take],
        pos_se=pos_se,
        pos_off=pos_off,
    )
