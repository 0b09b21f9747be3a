"""Searches and memory at metropolitan scale: what one search of an epoch costs on the generated 260,000-node
city (``bench.metro.metro_city``), and what the city's search structures and a dispatch thread's scratch
hold.

Every search runs on the project's own code paths, as an epoch runs them: ``road_graph``'s contracted forward
graph, a workspace of the city's scratch pool (``scratch_pool(graph).take()``), ``dijkstra.run`` under the travel time
prepared for the graph, and a taxi's kappa tree with its costs computed as the search goes (``graph.Lazy``,
built as ``algorithm1._own_metric`` builds it, from the kappa graph of the city's kappa family). Measured:

1. the network's nodes and edges, the kept nodes (searched after contraction) and super-edges;
2. forward trees under the travel time from the sources, bounded by Step 3's reach (900 s) and unbounded:
   nodes settled and time;
3. the share of super-edges that enter no cell (``Lazy.fixed >= 0``) and of edges that enter one
   (``RoadGraph.crossing``);
4. a taxi's kappa tree (kappa 0.6, a taxi counted in no cell) over the ball of the reach, its costs computed
   as the search goes, against a tree over the same ball under the same metric prepared beforehand (for the
   whole network, as ``algorithm1._base_kappa`` prepares the in-trees' base metrics) and against the tree
   reading the epoch's base costs of the crossing super-edges (``algorithm1.Overlay``): the time to prepare
   each, the prepared metric's size, and the three trees' times (their labels are checked equal);
5. memory (numpy ``nbytes``): the city's network and grid crossings, the two search graphs, the landmark
   table, and one scratch (a forward and a reverse workspace and Algorithm 1's scratch);
6. one scipy reverse tree over the whole network, as the epoch benchmark's floor grows one per new task;
7. the ``limits`` scenario's Step 1 candidate pairs: its first epoch decided once (seeded: exact);
8. the contraction hierarchy under the travel time (``services.network.hierarchy``): its build time (once),
   arcs and memory, and ``TRIPS`` trips between nodes drawn uniformly over the whole network (a heavy
   epoch's riders, seed ``SEED``) found through it and goal-directed by the landmarks
   (``point_to_point.landmark_fastest_paths``), each way once on one thread after an untimed pair, the paths checked equal;
9. the kept nodes' order: item 2's bounded trees on the city as generated and on the same network with its
   nodes shuffled (an imported OpenStreetMap extract numbers them by when they were mapped), each with its
   search graphs' kept nodes numbered along a Hilbert curve (as the service numbers them) and in the order
   of the network's nodes (``graph.build_road_graph(..., along_curve=False)``): how far apart a
   super-edge's ends lie in that order, and the trees' times.

Sources: ``SOURCES`` nodes drawn around the city's centres (``bench.metro.near_centres``, 2.5 km spread, seed
``SEED``), where the epoch benchmark's taxis are; each of the service's searches timed as the best of ``REPEATS``
(each scipy tree once, on the first ``FLOOR_TREES`` sources), after one untimed search of each kind; the
prepared metric's build timed ``REPEATS + 2`` times. The gains are an epoch's with no counts yet.

    python -m bench.bench_search              # measures, writes docs/PERFORMANCE.md and docs/perf_search.json
    python -m bench.bench_search --no-write   # prints only
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import tempfile
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as cg
from numpy.typing import NDArray

from bench import bench_epoch, metro
from bench.report import PERFORMANCE, ROOT, stamp, write_section
from services.city import City
from services.dispatch import INITIAL_SLOTS, decide
from services.kernel.parallel import default_workers
from services.ledger import Ledger, ledger_view
from services.model import IntervalKey
from services.network import dijkstra, heaps, hierarchy, point_to_point
from services.network.graph import INF, US_PER_S, Costs, Lazy, RoadGraph, build_road_graph, road_graph
from services.network.scratch import Scratch, scratch_pool
from services.routing import algorithm1
from services.routing.algorithm1 import KappaGraph, kappa_graph
from services.sensing.gains import Gains, gain_table

SEED = 20261123
SOURCES = 30
REPEATS = 3
FLOOR_TREES = 10
TRIPS = 800
KAPPA = 0.6
SPREAD_M = 2_500.0
MB = 1e6


def summary(xs: list[float] | NDArray[Any]) -> dict[str, float]:
    """Median, min, max, quartiles and count of ``xs``."""
    a = np.asarray(xs, dtype=np.float64)
    return {
        "n": int(a.size),
        "median": float(np.median(a)),
        "min": float(a.min()),
        "max": float(a.max()),
        "q1": float(np.percentile(a, 25)),
        "q3": float(np.percentile(a, 75)),
    }


def best_of(fn: Callable[[], object], repeats: int) -> float:
    """The least wall time of ``repeats`` calls of ``fn``, in ms."""
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - started)
    return best * 1000.0


def _arrays(obj: object) -> Iterator[NDArray[Any]]:
    """Every numpy array held by ``obj`` (named tuples, dataclasses, dicts and lists, recursively)."""
    if isinstance(obj, np.ndarray):
        yield obj
    elif isinstance(obj, tuple | list):
        for x in obj:
            yield from _arrays(x)
    elif isinstance(obj, dict):
        for x in obj.values():
            yield from _arrays(x)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            yield from _arrays(getattr(obj, f.name))


def nbytes(*objs: object) -> int:
    """The bytes of the numpy arrays ``objs`` hold, each buffer counted once."""
    seen: set[tuple[int, int]] = set()
    total = 0
    for obj in objs:
        for a in _arrays(obj):
            key = (int(a.__array_interface__["data"][0]), a.nbytes)
            if key not in seen:
                seen.add(key)
                total += a.nbytes
    return total


def sources(city: City, n: int, seed: int, spread_m: float) -> NDArray[np.int64]:
    """``n`` nodes around the city's centres (``bench.metro.near_centres``), seeded."""
    return metro.near_centres(city, np.random.default_rng(seed), n, spread_m)


def gains(city: City) -> Gains:
    """An epoch's gain table with no counts yet (every cell's first visit still to gain): ``INITIAL_SLOTS``
    intervals from a minute into the first interval of the horizon on 2026-11-23 (as ``warm_up`` builds its
    epochs' times)."""
    hz = city.horizon
    k0 = IntervalKey((dt.date(2026, 11, 23) - dt.date(1970, 1, 1)).days * hz.per_day)
    return gain_table(city, {}, k0, INITIAL_SLOTS, hz.interval_start_s(k0) + 60.0)


def sizes(graph: RoadGraph, kt: KappaGraph) -> dict[str, float]:
    """Items 1 and 3: the network's and the search graph's sizes, the shares of super-edges that enter no
    cell and of edges that enter one."""
    fg = graph.forward
    return {
        "nodes": graph.n_nodes,
        "edges": graph.n_edges,
        "kept": int(fg.kept.shape[0]),
        "super_edges": int(fg.se_tail.shape[0]),
        "crossing_edges": int(graph.crossing.shape[0]),
        "super_edges_no_cell_share": float(np.mean(kt.fixed >= 0)),
        "edges_entering_a_cell_share": float(graph.crossing.shape[0] / graph.n_edges),
    }


def _settled(ws: heaps.Workspace) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The kept nodes the last search in ``ws`` settled (sorted) and their costs."""
    touched = ws.touched[: int(ws.info[2])]
    done = np.sort(touched[ws.state[touched] == -2])
    return done, ws.cost[done].copy()


def time_trees(
    graph: RoadGraph,
    ws: heaps.Workspace,
    src: NDArray[np.int64],
    reach_us: int,
    repeats: int,
    limits: tuple[str, ...] = ("bounded", "whole"),
) -> dict[str, Any]:
    """Item 2: per source, the forward tree under the travel time bounded by ``reach_us`` and the whole
    tree: nodes settled and the best time of ``repeats``."""
    fg, ed, costs = graph.forward, graph.edges, graph.time_forward
    none = np.zeros(0, dtype=np.int64)
    out: dict[str, list[float]] = {
        "bounded_ms": [],
        "bounded_settled": [],
        "whole_ms": [],
        "whole_settled": [],
    }
    for limit, name in ((reach_us, "bounded"), (INF, "whole")):
        if name not in limits:
            continue
        dijkstra.run(fg, ed, costs, int(src[0]), limit, none, ws)  # untimed: workspace and kernel warm
        for v in src.tolist():
            out[f"{name}_ms"].append(
                best_of(partial(dijkstra.run, fg, ed, costs, v, limit, none, ws), repeats)
            )
            out[f"{name}_settled"].append(float(_settled(ws)[0].shape[0]))
    return {k: summary(v) for k, v in out.items() if v} | {"raw": out}


def node_order(city: City, src: NDArray[np.int64], reach_us: int, repeats: int, seed: int) -> dict[str, Any]:
    """Item 9: the bounded trees of item 2 on ``city`` and on it shuffled, its kept nodes numbered along the
    curve and in the network's order; per variant the median distance between a super-edge's ends in that
    numbering and the trees' times."""
    other, index = metro.shuffled(city, seed)
    out: dict[str, Any] = {}
    for name, c, s in (("generated", city, src), ("shuffled", other, index[src])):
        for curve in (True, False):
            graph = build_road_graph(c, along_curve=curve)
            fg = graph.forward
            trees = time_trees(graph, heaps.workspace(graph), s, reach_us, repeats, ("bounded",))
            out[f"{name}_{'curve' if curve else 'nodes'}"] = {
                "gap": float(np.median(np.abs(fg.se_tail - fg.se_head))),
                "ms": trees["bounded_ms"],
                "settled": trees["raw"]["bounded_settled"],
            }
            del graph, fg
    return out


def precomputed_metric(kt: KappaGraph, gn: Gains, kappa: float) -> Costs:
    """Taxi's kappa metric (a taxi counted in no cell: the base one) prepared for the whole forward graph
    beforehand, as ``algorithm1._base_kappa`` prepares the in-trees' base metrics for the reverse one."""
    base = algorithm1._base_kappa(kt._replace(rg=kt.fg), gn, np.array([kappa]), True)
    return Costs(base.edge[0], base.se[0], int(base.width[0]), int(base.span[0]))


def lazy_metric(kt: KappaGraph, scratch: Scratch, gn: Gains, q: int, kappa: float) -> tuple[Costs, Lazy]:
    """Taxi's kappa ``kappas[q]`` metric computed as the search goes, as ``algorithm1._own_metric`` builds
    it in an epoch (a taxi counted in no cell: its zero mask clear)."""
    sc = algorithm1.route_scratch(scratch, gn)
    umax = float(algorithm1._umax_scan(kt, gn, sc.zmask))
    costs = Costs(sc.edge_cost, sc.se_cost, int(kt.floor_width[q]), int(kt.floor_span[q]))
    return costs, Lazy(True, kappa, umax, gn.term[0], sc.zmask[0], kt.fixed)


def overlay_metric(
    kt: KappaGraph, scratch: Scratch, gn: Gains, kappas: tuple[float, ...], q: int, umax: float
) -> tuple[Costs, Lazy]:
    """Taxi's kappa ``kappas[q]`` metric reading the epoch's base costs of the crossing super-edges (an
    ``algorithm1.Overlay`` built here, as Step 3 builds it when many taxis grow their own trees; a taxi
    counted in no cell marks none of them)."""
    sc = algorithm1.route_scratch(scratch, gn)
    over = algorithm1._overlay_base(kt, gn, np.asarray(kappas, dtype=np.float64), umax)
    return algorithm1._own_metric_over(
        kt, sc, gn, q, kappas[q], umax, over.own[q], int(over.width[q]), int(over.span[q])
    )


def kappa_trees(
    kt: KappaGraph,
    kappas: tuple[float, ...],
    scratch: Scratch,
    gn: Gains,
    src: NDArray[np.int64],
    limit: int,
    repeats: int,
) -> dict[str, Any]:
    """Item 4: per source, the lazily costed kappa tree over the ball of ``limit`` against the tree under the
    same metric prepared beforehand (same nodes settled, same labels: checked); the preparation's time and
    size."""
    q = kappas.index(KAPPA)
    pre = precomputed_metric(kt, gn, KAPPA)  # untimed: kernel loaded
    build_ms = [best_of(partial(precomputed_metric, kt, gn, KAPPA), 1) for _ in range(repeats + 2)]
    costs, lazy = lazy_metric(kt, scratch, gn, q, KAPPA)
    fg, ed, ws = kt.fg, kt.ed, scratch.forward
    none = np.zeros(0, dtype=np.int64)
    over_costs, over_lazy = overlay_metric(kt, scratch, gn, kappas, q, lazy.umax)
    overlay_ms = [
        best_of(partial(overlay_metric, kt, scratch, gn, kappas, q, lazy.umax), 1) for _ in range(repeats + 2)
    ]
    out: dict[str, list[float]] = {
        "lazy_ms": [],
        "precomputed_ms": [],
        "overlay_ms": [],
        "ratio": [],
        "settled": [],
    }
    dijkstra.grow(fg, ed, costs, int(src[0]), limit, none, ws, lazy)  # untimed: kernels warm
    dijkstra.run(fg, ed, pre, int(src[0]), limit, none, ws)
    dijkstra.grow(fg, ed, over_costs, int(src[0]), limit, none, ws, over_lazy)
    for v in src.tolist():
        t_lazy = best_of(partial(dijkstra.grow, fg, ed, costs, v, limit, none, ws, lazy), repeats)
        got = _settled(ws)
        t_pre = best_of(partial(dijkstra.run, fg, ed, pre, v, limit, none, ws), repeats)
        want = _settled(ws)
        t_over = best_of(partial(dijkstra.grow, fg, ed, over_costs, v, limit, none, ws, over_lazy), repeats)
        read = _settled(ws)
        for other, name in ((want, "prepared"), (read, "overlay")):
            if not (np.array_equal(got[0], other[0]) and np.array_equal(got[1], other[1])):
                raise AssertionError(f"source {v}: the lazy and the {name} kappa trees differ")
        out["lazy_ms"].append(t_lazy)
        out["precomputed_ms"].append(t_pre)
        out["overlay_ms"].append(t_over)
        out["ratio"].append(t_lazy / t_pre)
        out["settled"].append(float(got[0].shape[0]))
    res: dict[str, Any] = {k: summary(v) for k, v in out.items()}
    res["build_ms"] = summary(build_ms)
    res["overlay_build_ms"] = summary(overlay_ms)
    res["metric_mb"] = nbytes(pre.edge, pre.se) / MB
    nonzero = sum(1 for k in kappas if k != 0.0)
    res["family_mb"] = nonzero * res["metric_mb"]  # one such metric per kappa > 0 of the family
    res["family_kappas"] = list(kappas)
    res["kappa"] = KAPPA
    res["raw"] = out
    return res


def memory(city: City, graph: RoadGraph, kt: KappaGraph, scratch: Scratch, gn: Gains) -> dict[str, float]:
    """Item 5, in MB: the city's network and grid crossings, the search graphs (edges, forward and reverse,
    the travel time prepared for each), Algorithm 1's kappa graph, the landmark table, and one scratch."""
    sc = algorithm1.route_scratch(scratch, gn)
    own = [getattr(sc, f) for f in sc._fields if f not in ("forward", "reverse")]  # those have rows
    out = {
        "network": nbytes(city.network) / MB,
        "grid_crossings": nbytes(city.edge_cells, city.cell_weight, city.interval_weight) / MB,
        "search_graphs": nbytes(graph) / MB,
        "kappa_graph": nbytes(kt.fixed, kt.floor_width, kt.floor_span) / MB,
        "landmarks": nbytes(point_to_point.landmarks(graph)) / MB,
        "forward_workspace": nbytes(scratch.forward) / MB,
        "reverse_workspace": nbytes(scratch.reverse) / MB,
        "algorithm1_scratch": nbytes(*own) / MB,
        "gain_slots": float(gn.term.shape[0]),
        "cells": float(gn.term.shape[1]),
    }
    out["city_and_graphs"] = (
        out["network"] + out["grid_crossings"] + out["search_graphs"] + out["kappa_graph"]
    )
    out["scratch"] = out["forward_workspace"] + out["reverse_workspace"] + out["algorithm1_scratch"]
    return out


def floor_trees(city: City, src: NDArray[np.int64]) -> dict[str, Any]:
    """Item 6: one scipy reverse tree over the whole network per source, as ``bench_epoch.floor_once`` grows
    one per new task's POI (the reversed travel-time matrix built once, untimed)."""
    net = city.network
    reverse = sp.csr_matrix((net.edge_time_s, (net.edge_v, net.edge_u)), shape=(net.n_nodes, net.n_nodes))
    cg.dijkstra(reverse, indices=src[:1])
    ms = [best_of(partial(cg.dijkstra, reverse, indices=src[i : i + 1]), 1) for i in range(len(src))]
    return summary(ms) | {"raw": ms}


def trips(graph: RoadGraph, scratch: Scratch, n: int, seed: int) -> dict[str, Any]:
    """Item 8: the hierarchy's build (and write) into an empty store and its read back from it, size and
    memory, and ``n`` trips through it and goal-directed (the same paths, checked)."""
    with tempfile.TemporaryDirectory() as store:
        started = time.perf_counter()
        hierarchy.stored_or_built(graph, root=Path(store))
        build_s = time.perf_counter() - started
        started = time.perf_counter()
        hierarchy.stored_or_built(graph, root=Path(store))
        read_s = time.perf_counter() - started
    h = hierarchy.hierarchy(graph)  # the service's own, as an epoch gets it
    if h is None:
        return {"build_s": build_s, "read_s": read_s, "arcs": None}
    rng = np.random.default_rng(seed)
    src, dst = rng.integers(graph.n_nodes, size=n), rng.integers(graph.n_nodes, size=n)
    hierarchy.fastest_paths(graph, scratch, src[:1], dst[:1])
    point_to_point.landmark_fastest_paths(graph, scratch.forward, src[:1], dst[:1])
    started = time.perf_counter()
    through = hierarchy.fastest_paths(graph, scratch, src, dst)
    ch_s = time.perf_counter() - started
    started = time.perf_counter()
    guided = point_to_point.landmark_fastest_paths(graph, scratch.forward, src, dst)
    alt_s = time.perf_counter() - started
    if any(not np.array_equal(a, b) for a, b in zip(through, guided, strict=True)):
        raise AssertionError("the hierarchy's paths differ from the search's")
    return {
        "build_s": build_s,
        "read_s": read_s,
        "arcs": int(h.arc_tail.shape[0]),
        "arcs_per_edge": h.arc_tail.shape[0] / graph.n_edges,
        "hierarchy_mb": nbytes(h) / MB,
        "lanes_mb": nbytes(scratch.extra[hierarchy.Lanes]) / MB,
        "trips": n,
        "through_s": ch_s,
        "guided_s": alt_s,
        "edges": int(sum(len(p) for p in through)),
    }


def limits_candidates(city: City, sc: bench_epoch.Scenario) -> dict[str, int]:
    """Item 7: the scenario's first epoch (``bench_epoch.limits_epochs``) decided once; its Step 1 candidate
    pairs (instrumented taxi, rider) as ``decide``'s stats count them."""
    snap, tasks = next(bench_epoch.limits_epochs(city, sc, 1))
    view = ledger_view(Ledger(), (t.id for t in snap.taxis if t.instrumented), city.grid.n_cells)
    d = decide(city, view, snap, tasks, workers=default_workers())
    return {
        "step1_candidates": int(d.stats["step1_candidates"]),
        "riders": len(snap.riders),
        "instrumented": sum(1 for t in snap.taxis if t.instrumented),
        "taxis": len(snap.taxis),
    }


def measure(
    city: City,
    *,
    n_sources: int = SOURCES,
    seed: int = SEED,
    spread_m: float = SPREAD_M,
    reach_s: float = 900.0,
    repeats: int = REPEATS,
    floor_n: int = FLOOR_TREES,
) -> dict[str, Any]:
    """Items 1-6 on ``city`` (see the module docstring)."""
    started = time.perf_counter()
    graph = road_graph(city)
    point_to_point.landmarks(graph)
    print(f"graph and landmarks: {time.perf_counter() - started:.1f} s", flush=True)
    kappas = tuple(float(k) for k in city.params.kappas)
    kt = kappa_graph(
        graph, kappas
    )  # Algorithm 1's kappa graph for the city's kappa family, as an epoch gets it
    gn = gains(city)
    src = sources(city, n_sources, seed, spread_m)
    reach_us = int(round(reach_s * US_PER_S))
    with scratch_pool(graph).take() as scratch:
        res: dict[str, Any] = {
            "inputs": {
                "city": city.name,
                "sources": n_sources,
                "seed": seed,
                "spread_m": spread_m,
                "reach_s": reach_s,
                "repeats": repeats,
                "source_nodes": src.tolist(),
            },
            "sizes": sizes(graph, kt),
        }
        res["travel_time"] = time_trees(graph, scratch.forward, src, reach_us, repeats)
        print("travel-time trees done", flush=True)
        res["kappa"] = kappa_trees(kt, kappas, scratch, gn, src, reach_us, repeats)
        print("kappa trees done", flush=True)
        res["memory"] = memory(city, graph, kt, scratch, gn)
        res["hierarchy"] = trips(graph, scratch, TRIPS, seed)
        print("hierarchy done", flush=True)
    res["floor"] = floor_trees(city, src[:floor_n])
    print("floor trees done", flush=True)
    res["node_order"] = node_order(city, src, reach_us, repeats, seed)
    print("node orders done", flush=True)
    return res


def _range(s: dict[str, float], fmt: str = ".1f") -> str:
    return f"{s['median']:{fmt}} ({s['min']:{fmt}}-{s['max']:{fmt}})"


def write_report(res: dict[str, Any], doc: Path = PERFORMANCE) -> Path:
    """The section ``search`` of the performance document ``doc`` from the results ``res``."""
    inp, sz, tt, kp, mem, fl = (
        res[k] for k in ("inputs", "sizes", "travel_time", "kappa", "memory", "floor")
    )
    lim = res.get("limits")
    lines = [
        "## Searches and memory at metropolitan scale",
        "",
        stamp("python -m bench.bench_search"),
        "",
        "One search of an epoch on the generated metropolitan city (`bench/metro.py`, `metro.metro_city()`), run",
        "as an epoch runs it: `road_graph`'s contracted forward graph, a workspace of the city's scratch pool,",
        f"`dijkstra.run` under the travel time. Sources: {inp['sources']} nodes drawn around the city's centres",
        f"(`metro.near_centres`, {inp['spread_m']:,.0f} m spread, seed {inp['seed']}), where the epoch benchmark's",
        f"taxis are; each of the service's searches timed as the best of {inp['repeats']} after an untimed one,",
        f"median (min-max) over the sources. The bound is Step 3's reach ({inp['reach_s']:.0f} s). The gains",
        "are an epoch's with no counts yet.",
        "",
        f"- Network: {sz['nodes']:,} nodes, {sz['edges']:,} edges; searched after contraction: {sz['kept']:,} kept",
        f"  nodes, {sz['super_edges']:,} super-edges.",
        f"- Forward tree under the travel time bounded by the reach: {_range(tt['bounded_settled'], ',.0f')} nodes",
        f"  settled, {_range(tt['bounded_ms'], '.2f')} ms. The whole network: {_range(tt['whole_settled'], ',.0f')}",
        f"  settled, {_range(tt['whole_ms'], '.1f')} ms.",
        f"- Super-edges that enter no cell (`Lazy.fixed` >= 0): {sz['super_edges_no_cell_share'] * 100:.1f} %; edges",
        f"  that enter a cell (`RoadGraph.crossing`): {sz['crossing_edges']:,}, {sz['edges_entering_a_cell_share'] * 100:.1f} %.",
        f"- A taxi's kappa {kp['kappa']} tree (counted in no cell, gains of an epoch with no counts yet, {mem['gain_slots']:.0f}",
        "  intervals) over the ball of the reach under that metric, its costs computed as the search goes",
        "  (`graph.Lazy`, as `algorithm1._own_metric` builds it): "
        f"{_range(kp['lazy_ms'], '.2f')} ms, {_range(kp['settled'], ',.0f')} nodes",
        f"  settled; the same tree under the metric prepared beforehand for every edge: {_range(kp['precomputed_ms'], '.2f')} ms",
        f"  (the same labels, checked); lazy / prepared per source: {_range(kp['ratio'], '.2f')}. Preparing the",
        f"  metric (a pass over all {sz['edges']:,} edges and the super-edge sums, `algorithm1._base_kappa`):",
        f"  {_range(kp['build_ms'], '.1f')} ms; it holds {kp['metric_mb']:.1f} MB, {kp['family_mb']:.1f} MB for the",
        f"  family's {sum(1 for k in kp['family_kappas'] if k)} kappas above 0. The same tree reading the epoch's base costs",
        "  of the crossing super-edges (`algorithm1.Overlay`, as a taxi's trees read them in Step 3 when many",
        "  taxis grow their own; this taxi, counted in no cell, marks none of them to compute as it goes):",
        f"  {_range(kp['overlay_ms'], '.2f')} ms (the same labels, checked); that table for the family, once an",
        f"  epoch: {_range(kp['overlay_build_ms'], '.1f')} ms.",
        "- One scipy reverse tree over the whole network (the floor's, `cg.dijkstra` on the reversed matrix, one",
        f"  source, each timed once; the first {fl['n']} sources): {_range(fl, '.1f')} ms.",
    ]
    hy = res.get("hierarchy")
    if hy is not None and hy.get("arcs") is not None:
        lines += [
            "- The contraction hierarchy under the travel time (`hierarchy.hierarchy`): built (and written to an empty",
            f"  store, `services.network.stored`) in {hy['build_s']:.1f} s, read back in {hy.get('read_s', float('nan')):.2f} s,",
            f"  {hy['arcs']:,} arcs ({hy['arcs_per_edge']:.2f} per edge), {hy['hierarchy_mb']:.1f} MB, a thread's query scratch",
            f"  {hy['lanes_mb']:.1f} MB. {hy['trips']} trips between nodes drawn uniformly over the network (a heavy epoch's",
            f"  riders; {hy['edges']:,} edges in all), one thread: {hy['through_s'] * 1000:.0f} ms through it,",
            f"  {hy['guided_s'] * 1000:.0f} ms goal-directed by the landmarks (`point_to_point.landmark_fastest_paths`); the same paths, checked.",
        ]
    order = res.get("node_order")
    if order is not None:
        gen, shf = (order[f"{k}_curve"] for k in ("generated", "shuffled"))
        gen_n, shf_n = (order[f"{k}_nodes"] for k in ("generated", "shuffled"))
        lines += [
            "- The kept nodes' order (the bounded trees above, `graph.build_road_graph`): numbered along a Hilbert",
            "  curve over their positions, as the service numbers them, a super-edge's ends lie a median",
            f"  {gen['gap']:,.0f} kept nodes apart and a tree takes {_range(gen['ms'], '.2f')} ms; in the generator's order",
            f"  of the network's nodes {gen_n['gap']:,.0f} apart, {_range(gen_n['ms'], '.2f')} ms. The same network with its",
            "  nodes shuffled (an imported OpenStreetMap extract numbers them by when they were mapped): along the",
            f"  curve {shf['gap']:,.0f} apart, {_range(shf['ms'], '.2f')} ms; in the shuffled order {shf_n['gap']:,.0f} apart,",
            f"  {_range(shf_n['ms'], '.2f')} ms.",
        ]
    if lim is not None:
        lines += [
            f"- The `limits` scenario's first epoch ({lim['riders']:,} riders, {lim['taxis']:,} taxis of which",
            f"  {lim['instrumented']:,} instrumented; seeded): {lim['step1_candidates']:,} Step 1 candidate pairs",
            '  (`decide`\'s `stats["step1_candidates"]`).',
        ]
    lines += [
        "",
        "Memory (numpy `nbytes`, MB):",
        "",
        "| what | holds | MB |",
        "|---|---|---|",
        f"| network | node ids, lon/lat, x/y, edge ends, lengths, times, CSR | {mem['network']:.1f} |",
        f"| grid crossings | cells each edge enters (CSR), cell and interval weights | {mem['grid_crossings']:.1f} |",
        f"| search graphs | `RoadGraph`: per-edge arrays, forward and reverse contracted graphs, the travel time prepared for each | {mem['search_graphs']:.1f} |",
        f"| Algorithm 1's kappa graph | `Lazy.fixed` and the kappa family's bucket bounds | {mem['kappa_graph']:.1f} |",
        f"| **city and search graphs** | the four above | **{mem['city_and_graphs']:.1f}** |",
        f"| landmark table | travel times to and from 8 landmarks per node | {mem['landmarks']:.1f} |",
        f"| forward workspace | labels, queue, touched list, predecessor edges | {mem['forward_workspace']:.1f} |",
        f"| reverse workspace | the same for in-trees | {mem['reverse_workspace']:.1f} |",
        f"| Algorithm 1's scratch | zero mask and stamps over {mem['gain_slots']:.0f} x {mem['cells']:,.0f} cells, a lazy metric's edge and super-edge costs, tree evaluation, the cell sets of the goal-directed searches' stop | {mem['algorithm1_scratch']:.1f} |",
        f"| **one scratch (per dispatch thread)** | the three above | **{mem['scratch']:.1f}** |",
        "",
        "The raw numbers of the last run are in `docs/perf_search.json`.",
    ]
    return write_section("search", "\n".join(lines), doc)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--no-limits", action="store_true", help="skip the limits scenario's epoch")
    ap.add_argument(
        "--report-only", action="store_true", help="rewrite the section from docs/perf_search.json"
    )
    args = ap.parse_args(argv)
    path = ROOT / "docs" / "perf_search.json"
    if args.report_only:
        write_report(json.loads(path.read_text()))
        return 0
    started = time.perf_counter()
    res = measure(metro.metro_city())
    if not args.no_limits:
        sc = bench_epoch.SCENARIOS["limits"]
        res["limits"] = limits_candidates(bench_epoch.load_city(sc), sc)
        print(f"limits: {res['limits']}", flush=True)
    res["wall_s"] = time.perf_counter() - started
    print(json.dumps({k: v for k, v in res.items() if k != "inputs"}, indent=1, default=str), flush=True)
    if not args.no_write:
        path.write_text(json.dumps(res, indent=1) + "\n")
        print(f"wrote {write_report(res)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
