"""Step 3's reach (docs/METHOD.md, "Step 3 at scale"): where it applies, and that the bounded searches give
exactly the straightforward computation restricted to the pairs in reach.

The straightforward computation is one full tree per taxi and kappa (``plan_routes`` with no reach, from the
taxis' side), itself checked against the book in ``test_routing.py``; here it is checked against the book
again on a sample of taxis of the largest instance, a generated metropolitan city at a quarter of its size.
"""

from __future__ import annotations

import dataclasses
from functools import cache
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from numpy.typing import NDArray

from bench import metro
from bench.load import Centres, CentresDemand, Load, Platform
from services.city import City, DispatchParams
from services.citydata import load_city
from services.dispatch import decide
from services.ledger import Ledger, apply_decision, ledger_view
from services.matching.assignment import lexicographic_assignment
from services.model import CountsView, IntervalKey, Snapshot, Task
from services.network import point_to_point
from services.network.graph import INF, US_PER_S, RoadGraph, road_graph
from services.network.scratch import ScratchPool
from services.routing.algorithm1 import Plans, plan_routes, problem
from services.routing.step3 import PHI_BITS, step3_reach_us
from services.sensing.gains import Counted, Gains, counted_csr, gain_table
from tests import reference as ref

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"
KAPPAS = (0.0, 0.3, 0.6, 0.9)


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_no_reach_on_the_bundled_cities(name: str) -> None:
    """Both bundled cities take less than the default ``step3_reach_above_s`` (an hour) to cross, so every
    taxi stays a candidate for every POI there: the paper-scale and city-scale decisions are the method's."""
    city = load_city(BUNDLES / name)
    graph = road_graph(city)
    assert point_to_point.crossing_us(graph) < city.params.step3_reach_above_s * US_PER_S
    assert step3_reach_us(city, graph) == INF


@pytest.mark.slow
def test_the_reach_applies_on_the_metropolitan_city() -> None:
    """The generated metropolitan network (70 km across) takes well over an hour to cross: the default
    reach applies. Its crossing time is a lower bound on its diameter: a path that long exists."""
    city = metro.metro_city()
    graph = road_graph(city)
    crossing = point_to_point.crossing_us(graph)
    assert crossing > 3600 * US_PER_S
    assert step3_reach_us(city, graph) == int(city.params.step3_reach_s * US_PER_S)  # type: ignore[operator]
    lm = point_to_point.landmarks(graph)
    assert (lm[lm < INF] <= crossing).all()


def _metro(reach_s: float | None) -> City:
    """The generated metropolitan city at a quarter of its size, its reach applied whatever it takes to
    cross (``step3_reach_above_s`` 0) or switched off."""
    city = _small_metro()
    return dataclasses.replace(city, params=DispatchParams(step3_reach_s=reach_s, step3_reach_above_s=0.0))


@cache
def _small_metro() -> City:
    return metro.metro_city(scale=0.25)


@cache
def _state() -> tuple[CountsView, Snapshot, list[Task]]:
    """Six epochs of a platform's load on the small metropolitan city (700 taxis, 300 instrumented, 160
    riders, 40 new tasks an epoch), then the seventh epoch's snapshot, tasks and the taxis' counted cells,
    with counts drawn anew."""
    city = _metro(None)
    xy, weight = metro.centre_layout(city)
    demand = CentresDemand(city, Centres(city, xy, weight, 700.0), trip_median_m=2000.0, trip_max_m=8000.0)
    plat = Platform(city, Load(300, 400, 160, 40, seed=11), demand)
    ledger = Ledger()
    for e in range(7):
        snap, tasks = plat.next_epoch()
        ledger.tasks.update({t.id: t for t in tasks})
        view = ledger_view(ledger, (t.id for t in snap.taxis if t.instrumented), city.grid.n_cells)
        if e == 6:  # counts of 0-2 per cell (terms that differ from cell to cell: discounted routes win more)
            k0 = city.horizon.interval_of(snap.time_s)
            rng = np.random.default_rng(5)
            counts = {IntervalKey(k0 + s): rng.integers(0, 3, city.grid.n_cells) for s in range(2)}
            return CountsView(counts, view.visited), snap, list(ledger.tasks.values())
        d = decide(city, view, snap, list(ledger.tasks.values()), workers=2)
        apply_decision(ledger, d.visits, d.task_updates)
        plat.apply(d.rider_matches, d.task_assignments, d.expired_rider_ids)
    raise AssertionError("unreachable")


def _targets(snap: Snapshot, tasks: list[Task]) -> NDArray[np.int64]:
    """The open tasks' POIs in the order ``decide`` takes them (by scheduled time, then id; one a node)."""
    nodes: dict[int, None] = {}
    for t in sorted((t for t in tasks if t.is_open(snap.time_s)), key=lambda t: (t.scheduled_at_s, t.id)):
        nodes.setdefault(t.node, None)
    return np.fromiter(nodes, dtype=np.int64, count=len(nodes))


class Ctx(NamedTuple):
    graph: RoadGraph
    gn: Gains
    counted: Counted
    sources: NDArray[np.int64]
    targets: NDArray[np.int64]
    now: float


def _plans(city: City, reach_us: int, from_targets: bool | None, workers: int = 2) -> tuple[Plans, Ctx]:
    view, snap, tasks = _state()
    graph = road_graph(city)
    free = [t for t in snap.taxis if t.vacant and t.instrumented]
    k0 = city.horizon.interval_of(snap.time_s)
    gn = gain_table(city, view.counts, k0, 3, snap.time_s)
    counted = counted_csr(view.visited, [t.id for t in free], k0)
    sources = np.array([t.node for t in free], dtype=np.int64)
    targets = _targets(snap, tasks)
    pb = problem(gn, counted, sources, targets, KAPPAS, snap.time_s, reach_us)
    plans = plan_routes(graph, pb, workers, ScratchPool(graph), fastest_from_targets=from_targets)
    return plans, Ctx(graph, gn, counted, sources, targets, snap.time_s)


@pytest.mark.slow
@pytest.mark.parametrize("from_targets", [True, False])
def test_bounded_routes_are_the_straightforward_ones_in_reach(from_targets: bool) -> None:
    """With a reach of 7.5 minutes, from the POIs' side and from the taxis', every pair in reach gets the
    kappa, gain, time and length of one full tree per taxi and kappa, and no other pair gets a route; about
    a quarter of the pairs are in reach on this instance, some with a discounted route. A sample of taxis is
    checked against the book."""
    reach_us = 450 * US_PER_S
    full, ctx = _plans(_metro(None), INF, False)
    bounded, _ = _plans(_metro(450.0), reach_us, from_targets)
    in_reach = full.d0_us <= reach_us
    assert (
        0.02 < in_reach.mean() < 0.5 and full.kappa_index.shape[0] >= 60 and full.kappa_index.shape[1] >= 40
    )
    assert np.array_equal(bounded.candidate, in_reach)
    assert np.array_equal(bounded.d0_us[in_reach], full.d0_us[in_reach])
    for name in ("kappa_index", "gain", "time_s", "length_m"):
        assert np.array_equal(getattr(bounded, name)[in_reach], getattr(full, name)[in_reach]), name
    assert (bounded.kappa_index[~in_reach] == -1).all() and np.isnan(bounded.time_s[~in_reach]).all()
    assert (full.kappa_index[in_reach] > 0).sum() >= 10  # discounted routes are chosen in reach
    graph, gn, counted, sources, targets, now = ctx
    for i in range(0, len(sources), max(1, len(sources) // 4)):
        lo, hi = counted.ptr[i], counted.ptr[i + 1]
        zero = set(zip(counted.slot[lo:hi].tolist(), counted.cell[lo:hi].tolist(), strict=True))
        book = ref.algorithm1(graph, gn, zero, int(sources[i]), targets.tolist(), now, KAPPAS)
        for j, (kappa, _edges, g, t, length) in enumerate(book):
            assert KAPPAS[full.kappa_index[i, j]] == kappa
            assert full.gain[i, j] == pytest.approx(g, rel=1e-12, abs=1e-300)
            assert full.time_s[i, j] == pytest.approx(t, rel=1e-12)
            assert full.length_m[i, j] == pytest.approx(length, rel=1e-12)


@pytest.mark.slow
def test_step3_in_reach_is_the_assignment_over_the_pairs_in_reach() -> None:
    """decide with a reach matches the same taxis to the same POIs as the exact assignment (most matches,
    then most phi) over the straightforward computation's pairs in reach; with no reach, over every pair."""
    view, snap, tasks = _state()
    for reach_s in (450.0, None):
        city = _metro(reach_s)
        d = decide(city, view, dataclasses.replace(snap, riders=()), tasks, workers=2)
        full, ctx = _plans(city, INF, False)
        targets = ctx.targets
        ok = full.d0_us <= (INF if reach_s is None else int(reach_s * US_PER_S))
        phi = full.phi
        top = float(phi[ok].max(initial=0.0))
        phi_q = np.rint(phi / (top / 2.0**PHI_BITS)).astype(np.int64)
        rows, cols = np.nonzero(ok)
        sol = lexicographic_assignment(
            rows, cols, np.ones(len(rows), np.int64), phi_q[rows, cols], secondary_sense="max"
        )
        free = [t for t in snap.taxis if t.vacant and t.instrumented]
        expect = {
            (free[i].id, int(targets[j])) for i, j in zip(sol.rows.tolist(), sol.cols.tolist(), strict=True)
        }
        node_of = {t.id: t.node for t in tasks}
        got = {(a.taxi_id, node_of[a.task_id]) for a in d.task_assignments}
        assert d.stats["alg2_passes"] >= 1 and len(got) == len(expect) > 10
        assert got == expect
