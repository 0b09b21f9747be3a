"""Building the contraction hierarchy of a city's network under the travel time: the node order, the
witness searches and the shortcuts (``services.network.hierarchy`` answers the queries).

The hierarchy (Geisberger, Sanders, Schultes and Delling, 2008) orders the nodes and contracts them one by
one; contracting ``v`` adds a shortcut ``u -> w`` for each pair of its remaining neighbours unless a
*witness* path from ``u`` to ``w`` that avoids ``v`` is no worse than ``u -> v -> w``. Every comparison is
the canonical one (``services.network.graph``; ``services.network.hierarchy`` says why the hierarchy keeps
the least label between every two remaining nodes): a witness is taken only when its label is no larger,
and a witness search that gives up early adds the shortcut, which is merely redundant.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline
from services.network.graph import INF
from services.network.heaps import _less

__all__ = ["ARCS_PER_EDGE", "Hierarchy", "build", "contraction_order"]

ARCS_PER_EDGE = 3
"""Room for arcs (edges and shortcuts) per edge: a network that needs more (a uniform grid, where
contraction hierarchies are known to degrade) gets no hierarchy, and its paths are searched as before."""

WITNESS_SETTLED = 60
"""Most nodes a witness search settles before it gives up (and the shortcut is added): only the size of
the hierarchy and the time to build it depend on it."""

ESTIMATE_SETTLED = 12
"""The same while only counting the shortcuts a node would need, for the contraction order's keys."""


class Hierarchy(NamedTuple):
    """The contracted network. Arc ``x`` joins ``arc_tail[x] -> arc_head[x]`` with label ``arc_c[x],
    arc_a[x], arc_b[x]``; it is an original edge (``arc_edge[x] >= 0``) or the shortcut of arcs
    ``arc_lo[x]`` then ``arc_hi[x]``. The arcs that climb from ``u`` (to a higher node) are
    ``up[up_ptr[u]:up_ptr[u + 1]]``; the arcs that come down into ``w`` (from a higher node) are
    ``dn[dn_ptr[w]:dn_ptr[w + 1]]``. Indices are 32-bit (a metropolitan hierarchy has millions of arcs)."""

    rank: NDArray[np.int32]
    arc_tail: NDArray[np.int32]
    arc_head: NDArray[np.int32]
    arc_c: NDArray[np.int64]
    arc_a: NDArray[np.int64]
    arc_b: NDArray[np.int64]
    arc_edge: NDArray[np.int32]
    arc_lo: NDArray[np.int32]
    arc_hi: NDArray[np.int32]
    up_ptr: NDArray[np.int64]
    up: NDArray[np.int32]
    dn_ptr: NDArray[np.int64]
    dn: NDArray[np.int32]


# ---------------------------------------------------------------------------------------------------------
# Building: a pool of arcs with linked out- and in-lists per node, witness searches, the node order.


class _Pool(NamedTuple):
    """The arcs while the hierarchy is built, with room for ``ARCS_PER_EDGE`` per edge: ends, label, the
    original edge or the two parts, and the next arc out of the tail and into the head."""

    tail: NDArray[np.int32]
    head: NDArray[np.int32]
    c: NDArray[np.int64]
    a: NDArray[np.int64]
    b: NDArray[np.int64]
    edge: NDArray[np.int32]
    lo: NDArray[np.int32]
    hi: NDArray[np.int32]
    nout: NDArray[np.int32]
    nin: NDArray[np.int32]
    out_first: NDArray[np.int32]
    in_first: NDArray[np.int32]
    size: NDArray[np.int64]  # (1,) arcs used; -1 once the room ran out


@compiled
def _put(p: _Pool, u: int, w: int, c: int, a: int, b: int, edge: int, lo: int, hi: int) -> None:
    """Arc ``u -> w`` with this label, unless one is there already with a label no larger; a larger one is
    overwritten in place (it is no shortcut's part yet: parts are the arcs of a node being contracted).
    With no room left the pool is marked full (``size`` -1)."""
    x = p.out_first[u]
    while x >= 0:
        if p.head[x] == w:
            if _less(c, a, b, p.c[x], p.a[x], p.b[x]):
                p.c[x] = c
                p.a[x] = a
                p.b[x] = b
                p.edge[x] = edge
                p.lo[x] = lo
                p.hi[x] = hi
            return
        x = p.nout[x]
    x = p.size[0]
    if x < 0 or x == p.tail.shape[0]:
        p.size[0] = -1
        return
    p.size[0] = x + 1
    p.tail[x] = u
    p.head[x] = w
    p.c[x] = c
    p.a[x] = a
    p.b[x] = b
    p.edge[x] = edge
    p.lo[x] = lo
    p.hi[x] = hi
    p.nout[x] = p.out_first[u]
    p.out_first[u] = x
    p.nin[x] = p.in_first[w]
    p.in_first[w] = x


class _Witness(NamedTuple):
    """A witness search's scratch: labels, a binary heap of nodes and the nodes touched."""

    c: NDArray[np.int64]
    a: NDArray[np.int64]
    b: NDArray[np.int64]
    pos: NDArray[np.int64]
    heap: NDArray[np.int64]
    touched: NDArray[np.int64]


@compiled_inline
def _sift_up(
    c: NDArray[np.int64],
    a: NDArray[np.int64],
    b: NDArray[np.int64],
    pos: NDArray[np.signedinteger[Any]],
    heap: NDArray[np.signedinteger[Any]],
    i: int,
    v: int,
) -> None:
    """Put node ``v`` at heap place ``i`` (free, or its own with a label no larger than before) and sift it
    up; nodes are ordered by their labels ``(c, a, b)``."""
    while i > 0:
        parent = (i - 1) >> 1
        w = heap[parent]
        if not _less(c[v], a[v], b[v], c[w], a[w], b[w]):
            break
        heap[i] = w
        pos[w] = i
        i = parent
    heap[i] = v
    pos[v] = i


@compiled_inline
def _pop(
    c: NDArray[np.int64],
    a: NDArray[np.int64],
    b: NDArray[np.int64],
    pos: NDArray[np.signedinteger[Any]],
    heap: NDArray[np.signedinteger[Any]],
    size: int,
) -> int:
    """Take the heap's root out; returns the new size (the root is ``heap[0]`` before the call)."""
    size -= 1
    if size == 0:
        return 0
    v = heap[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        x = heap[child]
        if child + 1 < size:
            y = heap[child + 1]
            if _less(c[y], a[y], b[y], c[x], a[x], b[x]):
                child += 1
                x = y
        if not _less(c[x], a[x], b[x], c[v], a[v], b[v]):
            break
        heap[i] = x
        pos[x] = i
        i = child
    heap[i] = v
    pos[v] = i
    return size


@compiled
def _witness(
    p: _Pool, done: NDArray[np.bool_], workspace: _Witness, u: int, v: int, limit: int, settle: int
) -> int:
    """Labels of the least paths from ``u`` that avoid ``v`` and the contracted nodes, up to cost ``limit``
    and ``settle`` settled nodes (a label not final when it stops is still the label of a real path: a
    witness taken from it is one). Returns the number of nodes touched (to reset)."""
    n_t = 1
    workspace.touched[0] = u
    workspace.c[u] = 0
    workspace.a[u] = 0
    workspace.b[u] = 0
    workspace.heap[0] = u
    workspace.pos[u] = 0
    size = 1
    settled = 0
    while size > 0 and settled < settle:
        x = workspace.heap[0]
        size = _pop(workspace.c, workspace.a, workspace.b, workspace.pos, workspace.heap, size)
        workspace.pos[x] = -2
        settled += 1
        cx, ax, bx = workspace.c[x], workspace.a[x], workspace.b[x]
        if cx > limit:
            break
        y = p.out_first[x]
        while y >= 0:
            h = p.head[y]
            if h != v and not done[h] and workspace.pos[h] != -2:
                c = cx + p.c[y]
                if c <= limit:
                    a = ax + p.a[y]
                    b = bx + p.b[y]
                    if _less(c, a, b, workspace.c[h], workspace.a[h], workspace.b[h]):
                        if workspace.c[h] == INF:
                            workspace.touched[n_t] = h
                            n_t += 1
                        workspace.c[h] = c
                        workspace.a[h] = a
                        workspace.b[h] = b
                        if workspace.pos[h] < 0:
                            workspace.pos[h] = size
                            size += 1
                        _sift_up(
                            workspace.c,
                            workspace.a,
                            workspace.b,
                            workspace.pos,
                            workspace.heap,
                            workspace.pos[h],
                            h,
                        )
            y = p.nout[y]
    return n_t


@compiled_inline
def _clear(workspace: _Witness, n_t: int) -> None:
    for i in range(n_t):
        x = workspace.touched[i]
        workspace.c[x] = INF
        workspace.pos[x] = -1


@compiled
def _contract(
    p: _Pool, done: NDArray[np.bool_], workspace: _Witness, v: int, add: bool, settle: int
) -> tuple[int, int]:
    """Contract ``v`` (``add``) or only count what it would take: the shortcuts it needs and the arcs it
    removes from the remaining graph."""
    need = 0
    removed = 0
    x = p.out_first[v]
    while x >= 0:
        if not done[p.head[x]]:
            removed += 1
        x = p.nout[x]
    x = p.in_first[v]
    while x >= 0:
        u = p.tail[x]
        if done[u]:
            x = p.nin[x]
            continue
        removed += 1
        limit = 0
        y = p.out_first[v]
        while y >= 0:
            w = p.head[y]
            if w != u and not done[w]:
                limit = max(limit, p.c[x] + p.c[y])
            y = p.nout[y]
        n_t = _witness(p, done, workspace, u, v, limit, settle)
        y = p.out_first[v]
        while y >= 0:
            w = p.head[y]
            if w != u and not done[w]:
                c, a, b = p.c[x] + p.c[y], p.a[x] + p.a[y], p.b[x] + p.b[y]
                if _less(c, a, b, workspace.c[w], workspace.a[w], workspace.b[w]):
                    need += 1
                    if add:
                        _put(p, u, w, c, a, b, -1, x, y)
            y = p.nout[y]
        _clear(workspace, n_t)
        x = p.nin[x]
    return need, removed


@compiled
def _witness_scratch(n: int) -> _Witness:
    return _Witness(
        np.full(n, INF, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.full(n, -1, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
    )


@compiled_inline
def _priority(need: int, removed: int, deleted: int, level: int) -> int:
    """The order's key: twice the edge difference, the neighbours contracted and the level (the
    hierarchy's depth below the node), the usual mix for road networks; only speed depends on it."""
    return 2 * (need - removed) + deleted + level


@compiled
def contraction_order(p: _Pool, n: int) -> NDArray[np.int64]:
    """The nodes in the order they are contracted, least key first, the keys brought up to date lazily:
    a node's key is computed again when it comes first, and it is contracted only if it still is (its
    neighbours' counts of contracted neighbours and levels are kept as they change). Contracts them, the
    shortcuts going to the pool; stops (the order cut short) when the pool is full."""
    done = np.zeros(n, dtype=np.bool_)
    ws = _witness_scratch(n)
    deleted = np.zeros(n, dtype=np.int64)
    level = np.zeros(n, dtype=np.int64)
    # the queue is the labels' heap on (key, node, 0): least key first, ties to the smaller node
    key = np.zeros(n, dtype=np.int64)
    node = np.arange(n, dtype=np.int64)
    zero = np.zeros(n, dtype=np.int64)
    heap = np.zeros(n, dtype=np.int64)
    pos = np.full(n, -1, dtype=np.int64)
    for v in range(n):
        need, removed = _contract(p, done, ws, v, False, ESTIMATE_SETTLED)
        key[v] = _priority(need, removed, 0, 0)
        _sift_up(key, node, zero, pos, heap, v, v)
    size = n
    order = np.zeros(n, dtype=np.int64)
    for r in range(n):
        while True:
            v = heap[0]
            need, removed = _contract(p, done, ws, v, False, ESTIMATE_SETTLED)
            k = _priority(need, removed, deleted[v], level[v])
            if k <= key[v] or size == 1:
                break
            size = _pop(key, node, zero, pos, heap, size)
            key[v] = k
            _sift_up(key, node, zero, pos, heap, size, v)
            size += 1
        size = _pop(key, node, zero, pos, heap, size)
        pos[v] = -2
        _contract(p, done, ws, v, True, WITNESS_SETTLED)
        if p.size[0] < 0:
            return order[:r]
        done[v] = True
        order[r] = v
        _touch_neighbours(p, done, v, deleted, level)
    return order


@compiled_inline
def _unlink(first: NDArray[np.int32], nxt: NDArray[np.int32], owner: int, x: int) -> None:
    """Take arc ``x`` out of ``owner``'s list (``first``, ``nxt``: the out- or the in-lists); the other arcs
    keep their order."""
    y = first[owner]
    if y == x:
        first[owner] = nxt[x]
        return
    while y >= 0:
        z = nxt[y]
        if z == x:
            nxt[y] = nxt[x]
            return
        y = z


@compiled
def _touch_neighbours(
    p: _Pool, done: NDArray[np.bool_], v: int, deleted: NDArray[np.int64], level: NDArray[np.int64]
) -> None:
    """After contracting ``v``: its remaining neighbours' counts and levels, and its arcs taken out of their
    lists, where every later search would pass over them (the arcs stay in the pool)."""
    x = p.out_first[v]
    while x >= 0:
        w = p.head[x]
        if not done[w]:
            deleted[w] += 1
            level[w] = max(level[w], level[v] + 1)
            _unlink(p.in_first, p.nin, w, x)
        x = p.nout[x]
    x = p.in_first[v]
    while x >= 0:
        w = p.tail[x]
        if not done[w]:
            deleted[w] += 1
            level[w] = max(level[w], level[v] + 1)
            _unlink(p.out_first, p.nout, w, x)
        x = p.nin[x]


def _csr(
    owner: NDArray[np.int32], which: NDArray[np.int64], n: int
) -> tuple[NDArray[np.int64], NDArray[np.int32]]:
    """The arcs ``which``, grouped by their ``owner`` node: (pointers, arcs)."""
    order = np.argsort(owner[which], kind="stable")
    ptr = np.zeros(n + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(np.bincount(owner[which], minlength=n))
    return ptr, which[order].astype(np.int32)


def build(
    n: int,
    tail: NDArray[np.int64],
    head: NDArray[np.int64],
    cost: NDArray[np.int64],
    tie1: NDArray[np.int64],
    tie2: NDArray[np.int64],
) -> Hierarchy | None:
    """The hierarchy of the graph of ``n`` nodes and edges ``tail -> head`` with labels ``(cost, tie1,
    tie2)`` (cost >= 1); of parallel edges the one with the least label is kept, self-loops are dropped.
    None when it would take more than ``ARCS_PER_EDGE`` arcs per edge."""
    cap = max(64, ARCS_PER_EDGE * int(tail.shape[0]))

    def room(dtype: type) -> NDArray[Any]:
        return np.zeros(cap, dtype=dtype)

    p = _Pool(
        room(np.int32),
        room(np.int32),
        room(np.int64),
        room(np.int64),
        room(np.int64),
        room(np.int32),
        room(np.int32),
        room(np.int32),
        room(np.int32),
        room(np.int32),
        np.full(n, -1, dtype=np.int32),
        np.full(n, -1, dtype=np.int32),
        np.zeros(1, dtype=np.int64),
    )
    _load(p, tail.astype(np.int64), head.astype(np.int64), cost, tie1, tie2)
    order = contraction_order(p, n)
    if order.shape[0] < n:
        return None
    rank = np.empty(n, dtype=np.int32)
    rank[order] = np.arange(n, dtype=np.int32)
    k = int(p.size[0])
    arc_tail, arc_head = p.tail[:k].copy(), p.head[:k].copy()
    climbs = rank[arc_tail] < rank[arc_head]
    up_ptr, up = _csr(arc_tail, np.flatnonzero(climbs), n)
    dn_ptr, dn = _csr(arc_head, np.flatnonzero(~climbs), n)
    return Hierarchy(
        rank=rank,
        arc_tail=arc_tail,
        arc_head=arc_head,
        arc_c=p.c[:k].copy(),
        arc_a=p.a[:k].copy(),
        arc_b=p.b[:k].copy(),
        arc_edge=p.edge[:k].copy(),
        arc_lo=p.lo[:k].copy(),
        arc_hi=p.hi[:k].copy(),
        up_ptr=up_ptr,
        up=up,
        dn_ptr=dn_ptr,
        dn=dn,
    )


@compiled
def _load(
    p: _Pool,
    tail: NDArray[np.int64],
    head: NDArray[np.int64],
    cost: NDArray[np.int64],
    tie1: NDArray[np.int64],
    tie2: NDArray[np.int64],
) -> None:
    for e in range(tail.shape[0]):
        if tail[e] != head[e]:
            _put(p, tail[e], head[e], cost[e], tie1[e], tie2[e], e, -1, -1)
