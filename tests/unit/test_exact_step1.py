"""Step 1 is exact at the size where rounding once broke it: 300 instrumented taxis x 300 riders on the
Manhattan network, with many cells already counted by dozens of taxis (marginal gains of 1e-3 of a first
visit and less) and taxis counted in cells of their own.

The independent formulation shares no code with the service's matching: paths from the plain canonical
Dijkstra of ``tests/reference.py``, every pair's gain by the book in floating point, the largest total gain
from scipy's assignment on those floats, then the least total wait among the matchings of that gain from
a mixed-integer program (scipy's HiGHS).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import Bounds, LinearConstraint, linear_sum_assignment, milp
from scipy.sparse import coo_matrix

from services.citydata import load_city
from services.dispatch import decide
from services.model import CountsView, IntervalKey, Rider, RiderId, Snapshot, Taxi, TaxiId
from services.network.graph import road_graph
from services.sensing.grid import segment_cells
from tests import reference as ref

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"


def instance(seed: int, n_taxis: int, n_riders: int):
    city = load_city(BUNDLES / "manhattan")
    rng = np.random.default_rng(seed)
    n = city.network.n_nodes
    now = city.horizon.start_s("2026-11-23") + 1800.0
    k0 = city.horizon.interval_of(now)
    n_cells = city.grid.n_cells
    # most touched cells already counted by dozens of taxis, some by none
    touched = np.flatnonzero(city.cell_weight > 0)
    lam = np.zeros(n_cells, dtype=np.int64)
    lam[touched] = rng.integers(10, 80, touched.size) * (rng.random(touched.size) < 0.85)
    counts = {IntervalKey(k0): lam, IntervalKey(k0 + 1): lam // 2}
    taxis = tuple(Taxi(TaxiId(f"i{i}"), int(rng.integers(n)), True, True) for i in range(n_taxis))
    visited = {
        t.id: frozenset((IntervalKey(k0), int(c)) for c in rng.choice(touched, 6, replace=False))
        for t in taxis[::3]
    }
    riders = tuple(
        Rider(RiderId(f"r{j}"), int(rng.integers(n)), int(rng.integers(n)), now - 60.0)
        for j in range(n_riders)
    )
    return city, CountsView(counts, visited), Snapshot("e", now, riders, taxis)


def book_gain(city, counts, taxi, crossings, depart_s):
    """``tests.reference.gain`` with the edges' crossings computed once (``crossings``: per edge of the
    trip, its cells and the fractions of the edge where they are entered)."""
    seen: set[tuple[int, int]] = set()
    visited = counts.visited.get(taxi, frozenset())
    rho = city.params.rho
    total, t = 0.0, depart_s
    for te, cells, fracs in crossings:
        for c, f in zip(cells, fracs, strict=True):
            k = int(city.horizon.interval_of(t + float(f) * te))
            if (k, c) in seen:
                continue
            seen.add((k, c))
            if (k, c) in visited:
                continue
            arr = counts.counts.get(k)
            lam = int(arr[c]) if arr is not None else 0
            total += city.mu(k) * float(city.cell_weight[c]) * ((lam + 1) ** rho - lam**rho)
        t += te
    return total


def book_pairs(city, counts, snap):
    """Every (taxi, rider) pair within the pickup radius with its wait and its gain by the book."""
    graph = road_graph(city)
    ed = graph.edges
    net = city.network
    segments = {}
    node_taxis: dict[int, list[int]] = {}
    for i, t in enumerate(snap.taxis):
        node_taxis.setdefault(t.node, []).append(i)
    out = []
    for j, r in enumerate(snap.riders):
        label, succ = ref.canonical_tree(graph, ed.time_us, r.origin, reverse=True)
        trip = ref.tree_path(
            graph, ref.canonical_tree(graph, ed.time_us, r.origin)[1], r.origin, r.destination
        )
        for e in trip:
            if e not in segments:
                u, v = int(net.edge_u[e]), int(net.edge_v[e])
                cells, fracs = segment_cells(city.grid, net.x_m[u], net.y_m[u], net.x_m[v], net.y_m[v])
                segments[e] = (float(net.edge_time_s[e]), [int(c) for c in cells], list(fracs))
        crossings = [segments[e] for e in trip]
        for node, idx in node_taxis.items():
            if label[node] is None:
                continue
            pickup = ref.tree_path(graph, succ, r.origin, node, reverse=True)
            length = 0.0
            wait = 0.0
            for e in pickup:
                wait += float(ed.time_s[e])
                length += float(ed.length_m[e])
            if length > city.params.radius_m + 1e-6:
                continue
            for i in idx:
                gain = book_gain(city, counts, snap.taxis[i].id, crossings, snap.time_s + wait)
                out.append((i, j, wait, gain))
    return out


@pytest.mark.slow
def test_step1_is_the_exact_optimum_at_300_by_300():
    city, counts, snap = instance(11, 300, 300)
    d = decide(city, counts, snap, [], workers=2)
    pairs = book_pairs(city, counts, snap)
    positive = [p for p in pairs if p[3] > 0.0]
    assert len(positive) > 2000
    gains = np.array([p[3] for p in positive])
    first_visit = float(np.max(city.cell_weight)) * city.mu(city.horizon.interval_of(snap.time_s))
    assert gains.min() < 1e-2 * first_visit  # tiny but real gains are in play
    # the largest total gain (floats, scipy), then the least wait among matchings of that gain (HiGHS)
    n_t, n_r = len(snap.taxis), len(snap.riders)
    dense = np.zeros((n_t, n_r))
    for i, j, _w, g in positive:
        dense[i, j] = g
    rows, cols = linear_sum_assignment(dense, maximize=True)
    best_gain = float(dense[rows, cols].sum())
    k = len(positive)
    i_of = np.array([p[0] for p in positive])
    j_of = np.array([n_t + p[1] for p in positive])
    incidence = coo_matrix(
        (np.ones(2 * k), (np.concatenate([i_of, j_of]), np.tile(np.arange(k), 2))), shape=(n_t + n_r, k)
    )
    waits = np.array([p[2] for p in positive])
    res = milp(
        c=waits,
        constraints=[
            LinearConstraint(incidence, 0, 1),
            LinearConstraint(gains[None, :], best_gain * (1 - 1e-11), np.inf),
        ],
        integrality=np.ones(k),
        bounds=Bounds(0, 1),
    )
    assert res.status == 0
    best_wait = float(res.fun)
    # the service's Step 1 against it
    by_pair = {(snap.taxis[i].id, snap.riders[j].id): (w, g) for i, j, w, g in pairs}
    step1 = [m for m in d.rider_matches if m.step == 1]
    got_gain = math.fsum(by_pair[(m.taxi_id, m.rider_id)][1] for m in step1)
    got_wait = math.fsum(by_pair[(m.taxi_id, m.rider_id)][0] for m in step1)
    assert got_gain == pytest.approx(best_gain, rel=1e-11)
    assert got_wait <= best_wait + 1e-3
    for m in step1:  # the gain the service reports is the book's
        assert m.sensing_gain == pytest.approx(by_pair[(m.taxi_id, m.rider_id)][1], rel=1e-9)
    # no pair of positive gain is left with both ends free
    busy_t = {m.taxi_id for m in step1}
    busy_r = {m.rider_id for m in step1}
    assert not [
        p for p in positive if snap.taxis[p[0]].id not in busy_t and snap.riders[p[1]].id not in busy_r
    ]
    assert len(step1) == int((dense[rows, cols] > 0).sum())
