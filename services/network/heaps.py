"""A search's workspace and its queues: the 4-ary heap keyed on the cost alone and the bucket queue (a
ring of buckets with an occupancy bitmap), with the label order ``(cost, tie1, tie2)``, shared by every
search of ``services.network`` (the guided search's binary heap on whole labels is ``astar``'s own).

A search's state lives in a :class:`Workspace` of the caller's (one per thread); ``pred`` holds original
edge ids: the edge entering a node on its path from the source in a forward search, the edge leaving it
toward the root in a reverse one.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled_inline
from services.network.graph import (
    INF,
    RoadGraph,
)

__all__ = [
    "RING",
    "Workspace",
    "workspace",
]


RING = 1 << 18
"""Most buckets a workspace's bucket queue has; a metric whose ``span`` is larger than the workspace's ring
is searched with the heap."""


class Workspace(NamedTuple):
    """Scratch arrays of one search (sizes: K kept nodes, n original nodes)."""

    cost: NDArray[np.int64]  # (K,) label of each kept node
    tie1: NDArray[np.int64]
    tie2: NDArray[np.int64]
    pse: NDArray[np.int64]  # super-edge the label came along, -1 at the source
    pstart: NDArray[np.int64]  # offset on pse where it started (> 0: an interior source)
    state: NDArray[np.int64]  # -1 unseen, -2 settled, -3 dead end reached, >= 0 queued (heap: position)
    nxt: NDArray[np.int64]  # (K,) bucket lists (doubly linked) / heap keys
    prv: NDArray[np.int64]  # (K,) bucket lists / heap nodes
    ring: NDArray[np.int64]  # (RING,) first node of each bucket, -1 empty
    bits: NDArray[np.int64]  # (RING / 64,) non-empty buckets
    need: NDArray[np.bool_]
    unfolded: NDArray[np.bool_]  # (K,)
    touched: NDArray[np.int64]  # (K,) kept nodes whose entries the next search resets
    pred: NDArray[np.int64]  # (n,) original edge ids, valid on unfolded tree paths only
    info: NDArray[np.int64]  # [source, complete (1) or stopped early (0), number of touched nodes]
    hkey: NDArray[np.int64]  # (K, 3) run_guided's heap: the key of each entry, beside it


def workspace(graph: RoadGraph, reverse: bool = False) -> Workspace:
    """Fresh scratch arrays for searches on ``graph.forward`` (or ``graph.reverse``). The ring holds the
    travel time's span 16 times over (the discounted metrics of Algorithm 1 divide the cheapest super-edge
    by at most 1 / (1 - kappa)), at most ``RING`` buckets."""
    g = graph.reverse if reverse else graph.forward
    k = int(g.kept.shape[0])
    time_span = (graph.time_reverse if reverse else graph.time_forward).span
    ring = min(RING, 64 * ((16 * time_span + 63) // 64))
    return Workspace(
        cost=np.full(k, INF, dtype=np.int64),
        tie1=np.zeros(k, dtype=np.int64),
        tie2=np.zeros(k, dtype=np.int64),
        pse=np.full(k, -1, dtype=np.int64),
        pstart=np.zeros(k, dtype=np.int64),
        state=np.full(k, -1, dtype=np.int64),
        nxt=np.zeros(k, dtype=np.int64),
        prv=np.zeros(k, dtype=np.int64),
        ring=np.full(ring, -1, dtype=np.int64),
        bits=np.zeros(ring // 64, dtype=np.int64),
        need=np.zeros(k, dtype=np.bool_),
        unfolded=np.zeros(k, dtype=np.bool_),
        touched=np.zeros(k, dtype=np.int64),
        pred=np.full(graph.n_nodes, -1, dtype=np.int64),
        info=np.zeros(3, dtype=np.int64),
        hkey=np.zeros((k, 3), dtype=np.int64),
    )


@compiled_inline
def _less(c1: int, a1: int, b1: int, c2: int, a2: int, b2: int) -> bool:
    """Label (c1, a1, b1) before (c2, a2, b2)."""
    if c1 != c2:
        return c1 < c2
    if a1 != a2:
        return a1 < a2
    return b1 < b2


@compiled_inline
def _sift_up(
    keys: NDArray[np.int64], nodes: NDArray[np.int64], state: NDArray[np.int64], i: int, key: int, k: int
) -> None:
    while i > 0:
        parent = (i - 1) >> 2
        pk = keys[parent]
        if pk <= key:
            break
        keys[i] = pk
        w = nodes[parent]
        nodes[i] = w
        state[w] = i
        i = parent
    keys[i] = key
    nodes[i] = k
    state[k] = i


@compiled_inline
def _pop(keys: NDArray[np.int64], nodes: NDArray[np.int64], state: NDArray[np.int64], size: int) -> int:
    """Remove the root of the 4-ary heap (its node is ``nodes[0]`` before the call); new size."""
    size -= 1
    if size == 0:
        return 0
    key = keys[size]
    k = nodes[size]
    i = 0
    while True:
        first = 4 * i + 1
        if first >= size:
            break
        child = first
        ck = keys[first]
        last = min(first + 4, size)
        for c in range(first + 1, last):
            if keys[c] < ck:
                ck = keys[c]
                child = c
        if key <= ck:
            break
        keys[i] = ck
        w = nodes[child]
        nodes[i] = w
        state[w] = i
        i = child
    keys[i] = key
    nodes[i] = k
    state[k] = i
    return size


@compiled_inline
def _link(
    ring: NDArray[np.int64],
    bits: NDArray[np.int64],
    nxt: NDArray[np.int64],
    prv: NDArray[np.int64],
    b: int,
    h: int,
) -> None:
    """Put kept node ``h`` first in bucket ``b``."""
    first = ring[b]
    nxt[h] = first
    prv[h] = -1
    if first >= 0:
        prv[first] = h
    else:
        bits[b >> 6] |= np.int64(1) << (b & 63)
    ring[b] = h


@compiled_inline
def _unlink(
    ring: NDArray[np.int64],
    bits: NDArray[np.int64],
    nxt: NDArray[np.int64],
    prv: NDArray[np.int64],
    b: int,
    h: int,
) -> None:
    """Take kept node ``h`` out of bucket ``b``."""
    a = prv[h]
    z = nxt[h]
    if a >= 0:
        nxt[a] = z
    else:
        ring[b] = z
        if z < 0:
            bits[b >> 6] &= ~(np.int64(1) << (b & 63))
    if z >= 0:
        prv[z] = a


@compiled_inline
def _next_bucket(bits: NDArray[np.int64], span: int, p: int) -> int:
    """The first non-empty bucket at or after ``p``, cyclically (one must exist)."""
    n_words = (span + 63) >> 6
    i = p >> 6
    word = bits[i] & (np.int64(-1) << (p & 63))
    while word == 0:
        i += 1
        if i == n_words:
            i = 0
        word = bits[i]
    low = word & -word
    idx = 0
    if (low >> 32) != 0:
        idx += 32
        low >>= 32
    if (low >> 16) != 0:
        idx += 16
        low >>= 16
    if (low >> 8) != 0:
        idx += 8
        low >>= 8
    if (low >> 4) != 0:
        idx += 4
        low >>= 4
    if (low >> 2) != 0:
        idx += 2
        low >>= 2
    if (low >> 1) != 0:
        idx += 1
    return i * 64 + idx


@compiled_inline
def _offset_on(pos_se: NDArray[np.int64], pos_off: NDArray[np.int64], v: int, s: int) -> int:
    """Offset of interior node ``v`` on super-edge ``s`` (-1 when it does not lie on it)."""
    for j in range(2):
        if pos_se[v, j] == s:
            return int(pos_off[v, j])
    return -1


@compiled_inline
def _reset(workspace: Workspace) -> None:
    """Forget what the last search touched (the ring is left empty by every search)."""
    # the arrays taken out of the record first: read through it in the loop, each counts a reference per node
    touched, cost, state = workspace.touched, workspace.cost, workspace.state
    need, unfolded = workspace.need, workspace.unfolded
    for i in range(workspace.info[2]):
        k = touched[i]
        cost[k] = INF
        state[k] = -1
        need[k] = False
        unfolded[k] = False
