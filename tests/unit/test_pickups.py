"""The pickup candidates (``services.matching.legs.pickups``) against a plain canonical reverse Dijkstra per
rider (``tests.reference.canonical_tree``): every (taxi, rider) pair whose fastest pickup path is at most the
radius long, ordered by rider then taxi, with the path's wait in whole microseconds (its label), in
seconds and its length summed from the taxi along the path. Taxis crowd a few nodes, as at the limits,
where each node is looked at once per rider."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.citydata import load_city
from services.matching.legs import pickups
from services.network.graph import road_graph
from services.network.scratch import scratch_pool
from tests import reference as ref

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"


@pytest.fixture(scope="module")
def manhattan():
    city = load_city(BUNDLES / "manhattan")
    return city, road_graph(city)


@pytest.mark.parametrize("workers", [1, 2])
def test_pickups_are_the_pairs_within_the_radius_by_the_book(manhattan, workers: int) -> None:
    city, graph = manhattan
    ed = graph.edges
    net = city.network
    rng = np.random.default_rng(workers)
    centre = np.argmin(np.hypot(net.x_m - np.median(net.x_m), net.y_m - np.median(net.y_m)))
    near = np.flatnonzero(np.hypot(net.x_m - net.x_m[centre], net.y_m - net.y_m[centre]) < 2500.0)
    crowded = rng.choice(near, 12, replace=False)  # many taxis on a few nodes
    taxis = np.concatenate([rng.choice(crowded, 150), rng.choice(near, 150)]).astype(np.int64)
    origins = rng.choice(near, 25).astype(np.int64)
    radius = city.params.radius_m
    xy = np.column_stack((net.x_m, net.y_m))
    pk = pickups(graph, xy, origins, taxis, radius, workers, scratch_pool(graph))

    cost = ed.time_us
    want = []
    for j, origin in enumerate(origins.tolist()):
        label, pred = ref.canonical_tree(graph, cost, origin, reverse=True)
        for i, node in enumerate(taxis.tolist()):
            if label[node] is None:
                continue
            t = length = 0.0
            for e in ref.tree_path(graph, pred, origin, node, reverse=True):  # from the taxi
                t += float(ed.time_s[e])
                length += float(ed.length_m[e])
            if length <= radius + 1e-6:
                want.append((j, i, label[node][0], t, length))
    head = zip(pk.rider.tolist(), pk.taxi.tolist(), pk.wait_us.tolist(), pk.wait_s.tolist(), strict=True)
    got = [(*h, x) for h, x in zip(head, pk.length_m.tolist(), strict=True)]
    assert len(want) > 2000 and got == want
