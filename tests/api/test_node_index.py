"""The node indices an epoch's plain taxis and riders are resolved with
(``app.usecases.epoch_record.node_index``): each network's own, as ``Network.index_of`` gives them, while
more networks come and go than are kept."""

from __future__ import annotations

from app.usecases.epoch_record import node_index
from tests.citymaker import grid_city


def test_each_network_resolves_its_own_node_ids() -> None:
    cities = [grid_city(k, 300.0, cell_m=500.0) for k in range(2, 14)]  # more networks than are kept
    for _ in range(2):
        for city in cities:
            net = city.network
            index = node_index(city)
            assert len(index) == net.n_nodes
            assert all(index[node_id] == net.index_of(node_id) for node_id in net.node_ids.tolist())
