"""Idle drift: vacant taxis with no job move toward cells of high recent request density (docs/METHOD.md
section 10, docs/SIMULATOR.md "Idle drift").

Each grid cell the network touches has a hub, the node nearest the cell's centre. A taxi draws a hub among
the cells whose centres lie within the drift radius of its own cell's centre and follows the fastest path
toward it: the path of the hub's reverse shortest-path tree. Only the taxis of those cells ever follow a
hub's tree, so the tree is grown for them alone: a search from the hub over the reversed network stops once
it has settled every node of the cells within the radius (the paths from them are settled before them), and
only those nodes' paths are kept. Trees are grown the first time their hub is drawn and kept in a cache of
bounded size, least recently used first out: the drift's memory and time follow the hubs a run draws, not the
network's size (a tree grown again is the same tree).

The tree is Dijkstra's: a node's next node toward the hub is the one through which the search first reached
its final time (a later path of equal time does not replace it), nodes settled in order of (time, index);
its time is that path's float sum, edge by edge from the hub. ``tests/unit/sim/test_drift.py`` checks that
this is the tree of ``scipy.sparse.csgraph.dijkstra`` over the whole network on the bundled cities.
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.kernel.jit import compiled, compiled_inline

__all__ = ["Drift", "DriftMap", "DriftStats", "HubTree", "drift_map", "hubs_of_cells", "TREE_CACHE_BYTES"]

TREE_CACHE_BYTES = 256 * 2**20
"""Default bound on the trees a ``DriftMap`` keeps (bytes of their arrays)."""


class Drift(Protocol):
    """What the simulator asks of the idle drift (``DriftMap``; tests plug in reference implementations)."""

    @property
    def node_cell(self) -> NDArray[np.int64]:
        """The grid cell of every node."""
        ...

    @property
    def hubs(self) -> NDArray[np.int64]:
        """The hub node of each hub row."""
        ...

    def choose_target(self, node: int, density: NDArray[np.float64], rng: np.random.Generator) -> int:
        """Row of the hub a taxi at ``node`` drifts to, or -1."""
        ...

    def walk(self, hub_row: int, node: int, budget_s: float) -> tuple[int, float]:
        """Where a taxi at ``node`` gets toward hub ``hub_row`` in ``budget_s`` seconds, and the time used."""
        ...


@dataclass(frozen=True, slots=True)
class HubTree:
    """The part of a hub's reverse shortest-path tree the drift can use: the kept nodes (ascending), for each
    the position of its next node toward the hub in ``nodes`` (-1 at the hub) and its travel time to the
    hub in seconds."""

    nodes: NDArray[np.int64]
    next_pos: NDArray[np.int64]
    time_to: NDArray[np.float64]

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays."""
        return int(self.nodes.nbytes + self.next_pos.nbytes + self.time_to.nbytes)


@dataclass(frozen=True, slots=True)
class DriftStats:
    """What a ``DriftMap`` has done: trees grown (again, after an eviction, included), trees evicted, nodes
    the searches settled, trees and bytes held now."""

    grown: int
    evicted: int
    settled: int
    held: int
    held_bytes: int


def hubs_of_cells(
    city: City,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """The cells that hold at least one node (ascending), their hubs (the member nearest the cell's centre;
    the lowest index on ties), the centres' x and y, and every node's cell."""
    net, grid = city.network, city.grid
    col = np.floor((net.x_m - grid.origin_x_m) / grid.cell_m).astype(np.int64)
    row = np.floor((net.y_m - grid.origin_y_m) / grid.cell_m).astype(np.int64)
    node_cell = row * grid.n_cols + col
    by_cell = np.argsort(node_cell, kind="stable")  # members of a cell in ascending node order
    cells, first = np.unique(node_cell[by_cell], return_index=True)
    bounds = np.append(first, node_cell.size)
    hubs = np.empty(cells.size, dtype=np.int64)
    cx = np.empty(cells.size)
    cy = np.empty(cells.size)
    for i, c in enumerate(cells):
        members = by_cell[bounds[i] : bounds[i + 1]]
        cx[i] = grid.origin_x_m + (c % grid.n_cols + 0.5) * grid.cell_m
        cy[i] = grid.origin_y_m + (c // grid.n_cols + 0.5) * grid.cell_m
        d2 = (net.x_m[members] - cx[i]) ** 2 + (net.y_m[members] - cy[i]) ** 2
        hubs[i] = members[int(np.argmin(d2))]
    return cells, hubs, cx, cy, node_cell


class DriftMap:
    """The hubs of a city's touched cells, the cells within ``radius_m`` of each, and the hubs' trees grown
    on demand (module docstring). At most ``cache_bytes`` of trees are kept (at least the one in use).

    Thread-safe: one lock guards the search's scratch and the cache.
    """

    def __init__(self, city: City, radius_m: float, cache_bytes: int = TREE_CACHE_BYTES) -> None:
        if radius_m <= 0 or cache_bytes < 0:
            raise ValueError("the drift radius must be positive and the cache bound non-negative")
        self.radius_m = float(radius_m)
        self.cache_bytes = int(cache_bytes)
        self.cells, self._hubs, self.center_x_m, self.center_y_m, self._node_cell = hubs_of_cells(city)
        self.hub_of_cell = {int(c): i for i, c in enumerate(self.cells)}
        node_row = np.searchsorted(self.cells, self._node_cell)  # the hub row of every node's cell
        self._members = np.argsort(node_row, kind="stable")
        self._member_ptr = np.searchsorted(node_row[self._members], np.arange(self.cells.size + 1))
        self._node_row = node_row
        reverse = city.network.csr(city.network.edge_time_s).T.tocsr()  # in-edges of every node
        self._reverse = _Reverse(
            reverse.indptr.astype(np.int64), reverse.indices.astype(np.int64), reverse.data.astype(np.float64)
        )
        self._near: dict[int, NDArray[np.int64]] = {}
        self._trees: OrderedDict[int, HubTree] = OrderedDict()
        self._held_bytes = 0
        self._grown = self._evicted = self._settled = 0
        self._scratch: _Scratch | None = None
        self._lock = threading.Lock()

    @property
    def node_cell(self) -> NDArray[np.int64]:
        """The grid cell of every node."""
        return self._node_cell

    @property
    def hubs(self) -> NDArray[np.int64]:
        """The hub node of each hub row (row ``i`` is cell ``cells[i]``)."""
        return self._hubs

    def near(self, row: int) -> NDArray[np.int64]:
        """Hub rows whose cell centre lies within the radius of row ``row``'s (itself included), ascending."""
        got = self._near.get(row)
        if got is None:
            d2 = (self.center_x_m - self.center_x_m[row]) ** 2 + (self.center_y_m - self.center_y_m[row]) ** 2
            got = self._near[row] = np.flatnonzero(d2 <= self.radius_m**2)
        return got

    def choose_target(self, node: int, density: NDArray[np.float64], rng: np.random.Generator) -> int:
        """Row of the hub a taxi at ``node`` drifts to: a cell within the radius (centre to centre, the
        taxi's own cell included), drawn with probability proportional to its recent request count
        ``density[cell]``; ``-1`` when no cell nearby saw a request (or the drawn hub cannot be reached)."""
        near = self.near(int(self._node_row[node]))
        w = density[self.cells[near]]
        total = float(w.sum())
        if total <= 0.0:
            return -1
        pick = int(near[int(np.searchsorted(np.cumsum(w), rng.random() * total, side="right"))])
        tree = self.tree(pick)
        at = int(np.searchsorted(tree.nodes, node))
        if at == tree.nodes.size or int(tree.nodes[at]) != node:
            return -1
        return pick

    def walk(self, hub_row: int, node: int, budget_s: float) -> tuple[int, float]:
        """Follow the tree toward hub ``hub_row`` from ``node`` for at most ``budget_s`` seconds of travel.

        Returns the node reached (the taxi stops at the last node it can reach in time) and the time used.
        """
        tree = self.tree(hub_row)
        end, used = _walk(tree.nodes, tree.next_pos, tree.time_to, node, budget_s)
        return int(end), float(used)

    def tree(self, row: int) -> HubTree:
        """Hub ``row``'s tree, grown now unless the cache holds it."""
        with self._lock:
            tree = self._trees.get(row)
            if tree is not None:
                self._trees.move_to_end(row)
                return tree
            tree = self._grow(row)
            self._trees[row] = tree
            self._held_bytes += tree.nbytes
            while self._held_bytes > self.cache_bytes and len(self._trees) > 1:
                _, old = self._trees.popitem(last=False)
                self._held_bytes -= old.nbytes
                self._evicted += 1
            return tree

    def warm_up(self) -> None:
        """Compile the kernels (or load them from numba's cache) and allocate the search's scratch: the
        first hub's tree, grown and walked (it stays cached: the same tree a run would grow)."""
        if self.cells.size:
            self.walk(0, int(self._hubs[0]), 0.0)

    def stats(self) -> DriftStats:
        """Counts of the work done and the memory held."""
        with self._lock:
            return DriftStats(self._grown, self._evicted, self._settled, len(self._trees), self._held_bytes)

    def _grow(self, row: int) -> HubTree:
        if self._scratch is None:
            self._scratch = _scratch(self._node_row.size, self._reverse.time_s.size)
        s = self._scratch
        need = np.concatenate(
            [self._members[self._member_ptr[r] : self._member_ptr[r + 1]] for r in self.near(row)]
        )
        s.need[need] = True
        try:
            settled = _grow_tree(self._reverse, s, int(self._hubs[row]), need.size)
            nodes = np.sort(_kept(s, settled))
            pred = s.pred[nodes]
            next_pos = np.where(pred < 0, -1, np.searchsorted(nodes, pred))
            tree = HubTree(nodes, next_pos.astype(np.int64), s.time[nodes].copy())
        finally:
            s.need[need] = False
            _reset(s)
        self._grown += 1
        self._settled += settled
        return tree


class _Reverse(NamedTuple):
    """The reversed network as CSR: the in-edges of node ``v`` are ``indptr[v]:indptr[v + 1]``, from
    ``tail`` and taking ``time_s``."""

    indptr: NDArray[np.int64]
    tail: NDArray[np.int64]
    time_s: NDArray[np.float64]


class _Scratch(NamedTuple):
    """The search's arrays over the whole network, allocated once per map and reset after every tree:
    the nodes needed and marked kept, times, predecessors, states (0 unreached, 1 reached, 2 settled), the
    settled nodes in order, the reached ones (count first) and the heap."""

    need: NDArray[np.bool_]
    mark: NDArray[np.bool_]
    time: NDArray[np.float64]
    pred: NDArray[np.int64]
    state: NDArray[np.int8]
    order: NDArray[np.int64]
    touched: NDArray[np.int64]
    heap_t: NDArray[np.float64]
    heap_v: NDArray[np.int64]


def _scratch(n_nodes: int, n_edges: int) -> _Scratch:
    return _Scratch(
        need=np.zeros(n_nodes, dtype=np.bool_),
        mark=np.zeros(n_nodes, dtype=np.bool_),
        time=np.full(n_nodes, np.inf),
        pred=np.full(n_nodes, -1, dtype=np.int64),
        state=np.zeros(n_nodes, dtype=np.int8),
        order=np.empty(n_nodes, dtype=np.int64),
        touched=np.zeros(n_nodes + 1, dtype=np.int64),
        heap_t=np.empty(n_edges + 1),  # one entry per relaxation at most
        heap_v=np.empty(n_edges + 1, dtype=np.int64),
    )


@compiled_inline
def _before(t1: float, v1: int, t2: float, v2: int) -> bool:
    """The heap's order: by time, then by node index."""
    return t1 < t2 or (t1 == t2 and v1 < v2)


@compiled_inline
def _push(heap_t: NDArray[np.float64], heap_v: NDArray[np.int64], size: int, t: float, v: int) -> int:
    """Add (t, v) to the binary heap of ``size`` entries; the new size."""
    i = size
    while i > 0:
        p = (i - 1) // 2
        if not _before(t, v, heap_t[p], heap_v[p]):
            break
        heap_t[i], heap_v[i] = heap_t[p], heap_v[p]
        i = p
    heap_t[i], heap_v[i] = t, v
    return size + 1


@compiled_inline
def _pop(heap_t: NDArray[np.float64], heap_v: NDArray[np.int64], size: int) -> int:
    """Remove the root of the binary heap of ``size`` entries (read it before); the new size."""
    size -= 1
    t, v = heap_t[size], heap_v[size]  # the last entry sifts down from the root
    i = 0
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        if c + 1 < size and _before(heap_t[c + 1], heap_v[c + 1], heap_t[c], heap_v[c]):
            c += 1
        if not _before(heap_t[c], heap_v[c], t, v):
            break
        heap_t[i], heap_v[i] = heap_t[c], heap_v[c]
        i = c
    if size > 0:
        heap_t[i], heap_v[i] = t, v
    return size


@compiled
def _grow_tree(graph: _Reverse, s: _Scratch, hub: int, n_need: int) -> int:
    """Dijkstra from ``hub`` over the reversed network until the ``n_need`` nodes flagged in ``s.need`` are
    settled or nothing is left to reach: a binary heap of (time, node) with stale entries skipped; a node's
    predecessor changes only on a strictly shorter time. Returns how many nodes were settled (in
    ``s.order``)."""
    indptr, tail, time_s = graph.indptr, graph.tail, graph.time_s
    need, time, pred, state, order = s.need, s.time, s.pred, s.state, s.order
    touched, heap_t, heap_v = s.touched, s.heap_t, s.heap_v
    time[hub] = 0.0
    state[hub] = 1
    touched[0] = 1
    touched[1] = hub
    size = _push(heap_t, heap_v, 0, 0.0, hub)
    left = n_need
    k = 0
    while size > 0:
        d, v = heap_t[0], heap_v[0]
        size = _pop(heap_t, heap_v, size)
        if state[v] == 2 or d > time[v]:
            continue
        state[v] = 2
        order[k] = v
        k += 1
        if need[v]:
            left -= 1
            if left == 0:
                break
        for j in range(indptr[v], indptr[v + 1]):
            u = tail[j]
            if state[u] == 2:
                continue
            nd = d + time_s[j]
            if state[u] == 0 or nd < time[u]:
                if state[u] == 0:
                    state[u] = 1
                    touched[0] += 1
                    touched[touched[0]] = u
                time[u] = nd
                pred[u] = v
                size = _push(heap_t, heap_v, size, nd, u)
    return k


@compiled
def _kept(s: _Scratch, settled: int) -> NDArray[np.int64]:
    """The settled nodes on a path from a needed node to the hub (the needed ones included): marks spread
    from each node to its predecessor, latest settled first."""
    order, pred, need, mark = s.order[:settled], s.pred, s.need, s.mark
    n = 0
    for i in range(order.size - 1, -1, -1):
        v = order[i]
        if need[v] or mark[v]:
            mark[v] = True
            n += 1
            if pred[v] >= 0:
                mark[pred[v]] = True
    out = np.empty(n, dtype=np.int64)
    n = 0
    for i in range(order.size):
        if mark[order[i]]:
            out[n] = order[i]
            n += 1
    return out


@compiled
def _reset(s: _Scratch) -> None:
    """Clear what the last search wrote (its reached nodes' entries; times are rewritten on first reach)."""
    touched, state, pred, mark = s.touched, s.state, s.pred, s.mark
    for i in range(1, touched[0] + 1):
        v = touched[i]
        state[v] = 0
        pred[v] = -1
        mark[v] = False
    touched[0] = 0


@compiled
def _walk(
    nodes: NDArray[np.int64],
    next_pos: NDArray[np.int64],
    time_to: NDArray[np.float64],
    node: int,
    budget_s: float,
) -> tuple[int, float]:
    """Along the tree from ``node`` while the time used stays within ``budget_s``: the node reached and the
    time used (a node the tree does not hold stays where it is)."""
    i = np.searchsorted(nodes, node)
    if i == nodes.size or nodes[i] != node:
        return node, 0.0
    used = 0.0
    while True:
        j = next_pos[i]
        if j < 0:
            return nodes[i], used
        step = time_to[i] - time_to[j]
        if used + step > budget_s:
            return nodes[i], used
        used += step
        i = j


@functools.lru_cache(maxsize=4)
def drift_map(city: City, radius_m: float) -> DriftMap:
    """The city's drift map for ``radius_m``, made once per process (and city object) and kept with its
    trees: every run of the city's simulations shares it."""
    return DriftMap(city, radius_m)
