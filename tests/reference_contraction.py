"""The contraction of degree-2 chains written plainly in Python from its definition (the module docstring of
``services.network.contraction``): dictionaries, sets and lists, no compiled code. The tests compare the
compiled contraction with it array for array."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from services.network.contraction import Contraction

__all__ = ["plain_contract"]


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


def plain_contract(indptr: NDArray[np.int64], head: NDArray[np.integer]) -> Contraction:
    """``services.network.contraction.contract`` of the CSR graph ``(indptr, head)``, plainly."""
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
