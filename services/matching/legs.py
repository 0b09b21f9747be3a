"""Riders' legs: which taxis can pick a rider up (network pickup distance within the matching radius), the
pickup paths and the trip paths (docs/METHOD.md section 4). All paths are canonical fastest paths."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from services.kernel.jit import compiled
from services.kernel.parallel import parallel_map
from services.network import dijkstra, heaps, hierarchy, unfolding
from services.network.graph import US_PER_S, Costs, Edges, RoadGraph, SearchGraph
from services.network.scratch import ScratchPool

__all__ = ["Pickups", "pickups", "trips", "Leg"]


@dataclass(frozen=True, slots=True)
class Leg:
    """A path: its edges in travel order, length and travel time (summed in travel order)."""

    edges: NDArray[np.int64]
    length_m: float
    time_s: float


@dataclass(frozen=True, slots=True)
class Pickups:
    """Candidate (taxi, rider) pairs, ordered by rider then taxi: the pickup length, the wait (travel time
    in seconds, and in whole microseconds: the search's own cost, which the assignments compare)."""

    taxi: NDArray[np.int64]
    rider: NDArray[np.int64]
    length_m: NDArray[np.float64]
    wait_s: NDArray[np.float64]
    wait_us: NDArray[np.int64]


_Found = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]


class _Tree(NamedTuple):
    """The reverse search the pickups grow their in-trees with: the edges, the reverse graph, the scratch's
    reverse workspace and the travel-time costs."""

    ed: Edges
    rg: SearchGraph
    ws: heaps.Workspace
    time_costs: Costs


class _Hits(NamedTuple):
    """Per candidate (taxi) of a rider: whether its fastest pickup path is within the radius, that path's
    wait (whole microseconds and seconds) and length."""

    ok: NDArray[np.bool_]
    wait_us: NDArray[np.int64]
    wait_s: NDArray[np.float64]
    length_m: NDArray[np.float64]


@compiled
def _within(
    tree: _Tree,
    origin: int,
    limit_us: int,
    radius_m: float,
    nodes: NDArray[np.int64],
    hits: _Hits,
    slot: NDArray[np.int64],
    uniq: NDArray[np.int64],
) -> None:
    """One in-tree toward ``origin`` bounded by ``limit_us``; for each of ``nodes`` whether its fastest path
    to the origin is at most ``radius_m`` long, with that path's wait and length. A node several taxis
    stand on is resolved and walked once (``slot``: -1 per node on entry and on return; ``uniq``: room for
    the distinct nodes)."""
    ed, rg, ws, time_costs = tree.ed, tree.rg, tree.ws, tree.time_costs
    ok, wait_us, wait_s, length_m = hits.ok, hits.wait_us, hits.wait_s, hits.length_m
    n_u = 0
    for i in range(nodes.shape[0]):
        v = nodes[i]
        if slot[v] < 0:
            slot[v] = n_u
            uniq[n_u] = v
            n_u += 1
    un = uniq[:n_u]
    reached = np.zeros(n_u, dtype=np.bool_)
    dijkstra.run(rg, ed, time_costs, origin, limit_us, un, ws)
    unfolding.unfold_many(rg, ed, time_costs, limit_us, un, ws, reached)
    label = np.empty((3, n_u), dtype=np.int64)
    unfolding.labels(rg, ed, time_costs, limit_us, un, ws, label)
    u_ok = np.zeros(n_u, dtype=np.bool_)
    u_s = np.zeros(n_u)
    u_len = np.zeros(n_u)
    for q in range(n_u):
        if not reached[q]:
            continue
        t = 0.0
        length = 0.0
        x = un[q]
        while x != origin:
            e = ws.pred[x]
            t += ed.time_s[e]
            length += ed.length_m[e]
            x = ed.head[e]
        if length <= radius_m + 1e-6:
            u_ok[q] = True
            u_s[q] = t
            u_len[q] = length
    for i in range(nodes.shape[0]):
        q = slot[nodes[i]]
        ok[i] = u_ok[q]
        if u_ok[q]:
            wait_us[i] = label[0, q]
            wait_s[i] = u_s[q]
            length_m[i] = u_len[q]
    for q in range(n_u):
        slot[un[q]] = -1


@compiled
def _within_many(
    tree: _Tree,
    origins: NDArray[np.int64],
    ptr: NDArray[np.int64],
    nodes: NDArray[np.int64],
    limit_us: int,
    radius_m: float,
    hits: _Hits,
) -> None:
    """``_within`` for several riders in one call: rider ``q``'s candidates are ``nodes[ptr[q]:ptr[q+1]]``."""
    slot = np.full(tree.ws.pred.shape[0], -1, dtype=np.int64)
    uniq = np.empty(tree.ws.pred.shape[0], dtype=np.int64)
    for q in range(origins.shape[0]):
        lo, hi = ptr[q], ptr[q + 1]
        if hi > lo:
            part = _Hits(hits.ok[lo:hi], hits.wait_us[lo:hi], hits.wait_s[lo:hi], hits.length_m[lo:hi])
            _within(tree, origins[q], limit_us, radius_m, nodes[lo:hi], part, slot, uniq)


def pickups(
    graph: RoadGraph,
    xy: NDArray[np.float64],
    origins: NDArray[np.int64],
    taxi_nodes: NDArray[np.int64],
    radius_m: float,
    workers: int,
    pool: ScratchPool,
) -> Pickups:
    """Every (taxi, rider) pair whose fastest pickup path is at most ``radius_m`` long.

    ``xy`` holds the nodes' projected coordinates: only taxis within a slightly larger straight-line
    distance of a rider are looked at (a path is never shorter than the straight line; the margin covers
    the projection's scale), then one in-tree per rider, bounded by the time the slowest road takes to
    cover the radius, decides.
    """
    n_r = len(origins)
    empty_i = np.zeros(0, dtype=np.int64)
    if n_r == 0 or len(taxi_nodes) == 0:
        return Pickups(empty_i, empty_i, np.zeros(0), np.zeros(0), empty_i)
    limit_us = int(np.ceil(radius_m / graph.min_speed_mps * US_PER_S * (1 + 1e-9))) + 1
    taxi_tree = cKDTree(xy[taxi_nodes])
    reach = radius_m * 1.01 + 1.0
    ed = graph.edges

    def chunk(rs: Sequence[int]) -> list[_Found]:
        # the chunk's riders' candidates as arrays, ordered by rider then taxi (no Python list per rider:
        # at the limits, thousands of taxis near each of thousands of riders)
        orig = np.asarray([origins[j] for j in rs], dtype=np.int64)
        near = taxi_tree.sparse_distance_matrix(cKDTree(xy[orig]), reach, output_type="ndarray")
        by_rider = sp.csr_matrix(
            (np.ones(len(near), dtype=np.int8), (near["j"], near["i"])), shape=(len(rs), len(taxi_nodes))
        )
        del near
        by_rider.sort_indices()
        flat = by_rider.indices.astype(np.int64)
        ptr = by_rider.indptr.astype(np.int64)
        del by_rider
        nodes = taxi_nodes[flat]
        ok = np.zeros(len(flat), dtype=np.bool_)
        w_us = np.zeros(len(flat), dtype=np.int64)
        w_s = np.zeros(len(flat))
        length = np.zeros(len(flat))
        with pool.take() as scratch:
            tree = _Tree(ed, graph.reverse, scratch.reverse, graph.time_reverse)
            _within_many(tree, orig, ptr, nodes, limit_us, float(radius_m), _Hits(ok, w_us, w_s, length))
        out = []
        for q in range(len(rs)):
            sl = slice(ptr[q], ptr[q + 1])
            keep = ok[sl]
            out.append((flat[sl][keep], w_us[sl][keep], w_s[sl][keep], length[sl][keep]))
        return out

    found = parallel_map(chunk, range(n_r), workers)
    counts = [len(c) for c, _, _, _ in found]
    return Pickups(
        taxi=np.concatenate([c for c, _, _, _ in found]).astype(np.int64),
        rider=np.repeat(np.arange(n_r, dtype=np.int64), counts),
        length_m=np.concatenate([x for _, _, _, x in found]),
        wait_s=np.concatenate([x for _, _, x, _ in found]),
        wait_us=np.concatenate([x for _, x, _, _ in found]).astype(np.int64),
    )


def _leg(road_edges: Edges, edges: NDArray[np.int64]) -> Leg:
    return Leg(
        edges,
        float(road_edges.length_m[edges].sum()),
        float(np.cumsum(road_edges.time_s[edges])[-1]) if len(edges) else 0.0,
    )


def trips(graph: RoadGraph, pairs: Sequence[tuple[int, int]], workers: int, pool: ScratchPool) -> list[Leg]:
    """The fastest path of each (from, to) pair.

    Raises
    ------
    ValueError
        When a destination cannot be reached.
    """

    def chunk(ps: Sequence[tuple[int, int]]) -> list[Leg]:
        src = np.array([a for a, _ in ps], dtype=np.int64)
        dst = np.array([b for _, b in ps], dtype=np.int64)
        with pool.take() as scratch:
            return [_leg(graph.edges, e) for e in hierarchy.fastest_paths(graph, scratch, src, dst)]

    return parallel_map(chunk, pairs, workers)
