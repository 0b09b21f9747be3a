"""Step 3 of an epoch: vacant instrumented taxis still free matched to the open POIs (paper Section 4,
Eq. (13)-(16); docs/METHOD.md section 4).

A pair is a candidate when the POI lies within the taxi's reach (``step3_reach_us``); maximize the matches,
then the total phi of the enhanced A* routes (Algorithm 1, ``services.routing.algorithm1``). phi is compared
in units of 2**-``PHI_BITS`` of the largest, so the assignment is exact. Algorithm 2
(``services.routing.algorithm2``) then improves the matched routes together.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.city import City
from services.epoch import Epoch, until_fits
from services.kernel.parallel import parallel_map
from services.matching.assignment import lexicographic_assignment
from services.model import Taxi
from services.network import point_to_point
from services.network.graph import INF, US_PER_S, RoadGraph, road_graph
from services.routing.algorithm1 import Drive, Plans, Route, plan_routes, problem, route_pair
from services.sensing.gains import Counted, Gains, gain_table

__all__ = ["PHI_BITS", "Step3", "step3_monitoring_routes", "step3_reach", "step3_reach_us"]

PHI_BITS = 40
"""Step 3 compares phi in units of 2**-40 of the largest."""


@dataclass(frozen=True, slots=True)
class Step3:
    """Step 3's outcome before Algorithm 2, one entry per matched pair in each list: the free taxi (its index
    among the free taxis), its route and its fastest path to the same POI; and the interval slots the gain
    table the routes were planned on holds."""

    taxis: list[int]
    routes: list[Route]
    fastest: list[NDArray[np.int64]]
    n_slots: int


def step3_reach_us(city: City, graph: RoadGraph) -> int:
    """Step 3's reach in whole microseconds (``INF``: every taxi is a candidate for every POI): the city's
    ``step3_reach_s`` on a network that takes longer than ``step3_reach_above_s`` to cross
    (``point_to_point.crossing_us``), none on a smaller one (docs/METHOD.md section 4, "Step 3 at scale")."""
    p = city.params
    if p.step3_reach_s is None or point_to_point.crossing_us(graph) <= p.step3_reach_above_s * US_PER_S:
        return INF
    return int(round(p.step3_reach_s * US_PER_S))


def step3_reach(city: City) -> tuple[float | None, float]:
    """Step 3's reach on ``city`` in seconds (None: every taxi is a candidate for every POI) and the time the
    network takes to cross (``point_to_point.crossing_us``), which decides whether the reach applies."""
    graph = road_graph(city)
    reach = step3_reach_us(city, graph)
    return (None if reach >= INF else reach / US_PER_S), point_to_point.crossing_us(graph) / US_PER_S


def _plans(
    epoch: Epoch, counted: Counted, sources: NDArray[np.int64], targets: NDArray[np.int64], n_slots: int
) -> tuple[Plans, Gains, int]:
    """Algorithm 1 from every free taxi to every POI in its reach, on a gain table that grows until every
    route fits; the plans, the table and its slots."""
    reach_us = step3_reach_us(epoch.city, epoch.graph)

    def planned(n: int) -> tuple[tuple[Plans, Gains], int | None]:
        gn = gain_table(epoch.city, epoch.counts.counts, epoch.k0, n, epoch.now)
        pb = problem(gn, counted, sources, targets, epoch.city.params.kappas, epoch.now, reach_us)
        plans = plan_routes(epoch.graph, pb, epoch.workers, epoch.pool)
        return (plans, gn), (None if plans.max_slot < n else plans.max_slot + 1)

    (plans, gn), n_slots = until_fits(planned, n_slots)
    return plans, gn, n_slots


def _assign(plans: Plans) -> list[tuple[int, int]]:
    """The exact assignment over the pairs in reach: the most matches, then the largest total phi."""
    phi = plans.phi
    top = float(phi.max(initial=0.0))
    phi_q = (
        np.rint(phi / (top / 2.0**PHI_BITS)).astype(np.int64) if top > 0 else np.zeros(phi.shape, np.int64)
    )
    rows, cols = np.nonzero(plans.candidate)
    sol = lexicographic_assignment(
        rows, cols, np.ones(len(rows), dtype=np.int64), phi_q[rows, cols], secondary_sense="max"
    )
    return list(zip(sol.rows.tolist(), sol.cols.tolist(), strict=True))


def step3_monitoring_routes(
    epoch: Epoch, free: Sequence[Taxi], counted: Counted, targets: NDArray[np.int64], n_slots: int
) -> Step3:
    """Step 3 (Eq. 13-16) before Algorithm 2 over the free instrumented taxis ``free`` (their counted pairs
    in ``counted``, in their order) and the POI nodes ``targets``: a pair is a candidate when the POI lies
    within the taxi's reach; maximize the matches, then the total phi."""
    sources = np.array([t.node for t in free], dtype=np.int64)
    kappas = epoch.city.params.kappas
    plans, gn, n_slots = _plans(epoch, counted, sources, targets, n_slots)
    graph, pool = epoch.graph, epoch.pool

    def routes(chunk: Sequence[tuple[int, int]]) -> list[tuple[int, Route, NDArray[np.int64]]]:
        out = []
        with pool.take() as scratch:
            for i, j in chunk:
                q = int(plans.kappa_index[i, j])
                leg = Drive(i, int(sources[i]), int(targets[j]), int(plans.d0_us[i, j]))
                fastest = route_pair(graph, gn, counted, leg, kappas, 0, scratch)
                edges = (
                    fastest if kappas[q] == 0.0 else route_pair(graph, gn, counted, leg, kappas, q, scratch)
                )
                gain, time_s, length_m = (
                    float(plans.gain[i, j]),
                    float(plans.time_s[i, j]),
                    float(plans.length_m[i, j]),
                )
                out.append(
                    (i, Route(leg.source, leg.target, kappas[q], edges, gain, time_s, length_m, 0), fastest)
                )
        return out

    found = parallel_map(routes, _assign(plans), epoch.workers)
    return Step3([i for i, _, _ in found], [r for _, r, _ in found], [f for _, _, f in found], n_slots)
