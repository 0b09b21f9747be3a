"""Step 1's fixed-point gains by leg and slot (``gains.pair_gains_q``) are ``gains.eval_pairs``' integers,
crossing by crossing: on the Manhattan network, with departures spread over an interval's end (legs
walked in two slots), slots beyond the gain table, taxis counted in cells of several slots, and legs of
no edge."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.citydata import load_city
from services.model import IntervalKey, TaxiId
from services.network import heaps, point_to_point
from services.network.graph import road_graph
from services.sensing.gains import counted_csr, eval_pairs, fixed_point_unit, gain_table, pair_gains_q

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"


@pytest.fixture(scope="module")
def manhattan():
    city = load_city(BUNDLES / "manhattan")
    return city, road_graph(city)


@pytest.mark.parametrize("seed", range(6))
def test_the_gains_by_leg_and_slot_are_the_gains_crossing_by_crossing(manhattan, seed: int) -> None:
    city, graph = manhattan
    ed = graph.edges
    rng = np.random.default_rng(seed)
    n, n_cells = city.network.n_nodes, city.grid.n_cells
    touched = np.flatnonzero(city.cell_weight > 0)
    k0 = city.horizon.interval_of(city.horizon.start_s("2026-11-23") + 1800.0)
    end = city.horizon.interval_start_s(k0 + 1)  # the end of the epoch's interval
    now = end - 1500.0
    lam = np.zeros(n_cells, dtype=np.int64)
    lam[touched] = rng.integers(0, 40, touched.size)
    counts = {IntervalKey(k0): lam, IntervalKey(k0 + 1): lam // 3}

    legs = point_to_point.landmark_fastest_paths(
        graph, heaps.workspace(graph), rng.integers(n, size=60), rng.integers(n, size=60)
    )
    legs[0] = legs[0][:0]  # a leg of no edge (origin = destination)
    leg_ptr = np.zeros(len(legs) + 1, dtype=np.int64)
    leg_ptr[1:] = np.cumsum([len(leg) for leg in legs])
    leg_edges = np.concatenate(legs).astype(np.int64)

    taxis = [TaxiId(f"t{i}") for i in range(40)]
    visited = {
        t: frozenset(
            (IntervalKey(k0 + int(rng.integers(2))), int(c)) for c in rng.choice(touched, 8, replace=False)
        )
        for t in taxis[::2]
    }
    counted = counted_csr(visited, taxis, k0)
    pair_taxi = rng.integers(len(taxis), size=3000)
    pair_leg = rng.integers(len(legs), size=3000)
    # departures from now to past the interval's end: many legs cross it, some start after it
    pair_depart = now + rng.uniform(0.0, 1700.0, size=3000)
    crossing = 0
    for n_slots in (1, 2, 3):
        top = gain_table(city, counts, k0, n_slots, now)
        unit = fixed_point_unit(float(top.term.max()), 400)
        gn = gain_table(city, counts, k0, n_slots, now, unit=unit)
        _g, want, want_slot = eval_pairs(
            ed, gn, counted, pair_taxi, pair_leg, pair_depart, leg_ptr, leg_edges
        )
        got, got_slot = pair_gains_q(ed, gn, counted, pair_taxi, pair_leg, pair_depart, leg_ptr, leg_edges)
        assert np.array_equal(got, want) and got_slot == want_slot
        assert (want > 0).sum() > 1000 and want_slot >= 1
    for leg, depart in zip(pair_leg, pair_depart, strict=True):
        t = float(np.sum(ed.time_s[legs[leg]]))
        crossing += depart < end < depart + t
    assert crossing > 100  # the slow path (a leg in two slots) was taken too


def test_the_counted_pairs_are_each_taxis_pairs_from_the_first_slot_on() -> None:
    """``counted_csr``: row ``i`` holds taxi ``i``'s pairs of interval ``k0`` or later as (slot, cell), none
    of an earlier interval; a taxi with no visits (or only earlier ones) has an empty row; a taxi may
    repeat."""
    rng = np.random.default_rng(5)
    k0 = 100
    taxis = [TaxiId(f"t{i}") for i in range(30)] + [TaxiId("t4")]  # t4 twice: its pairs in both rows
    visited = {
        t: frozenset(
            (IntervalKey(int(k)), int(c))
            for k, c in zip(rng.integers(97, 103, 12), rng.integers(0, 50, 12), strict=True)
        )
        for t in taxis[:25:2]
    }
    visited[TaxiId("t24")] = frozenset({(IntervalKey(k0 - 1), 7)})
    counted = counted_csr(visited, taxis, k0)
    assert counted.ptr[0] == 0 and counted.ptr[-1] == counted.slot.size == counted.cell.size
    for i, t in enumerate(taxis):
        lo, hi = counted.ptr[i], counted.ptr[i + 1]
        got = sorted(zip(counted.slot[lo:hi].tolist(), counted.cell[lo:hi].tolist(), strict=True))
        want = sorted((k - k0, c) for k, c in visited.get(t, ()) if k >= k0)
        assert got == want, t
    assert counted.ptr[25] == counted.ptr[24]  # t24: an earlier interval only
    empty = counted_csr({}, taxis[:3], k0)
    assert empty.ptr.tolist() == [0, 0, 0, 0] and empty.slot.size == 0
