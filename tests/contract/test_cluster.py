"""On a real 3-master Redis Cluster every city works, whichever node owns its slot (``SD_REDIS_MODE=cluster``:
a store speaking to the one node in the URL would fail a city whose slot lives elsewhere with a MOVED reply,
then a reset connection). Each city's keys share one slot (the ``{city}`` hash tag), so its scripts and
transactions run on one node."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
import redis
from redis.cluster import RedisCluster

from app.adapters import RedisStore
from app.ports import EpochCommit, StoreUnavailable
from services.model import IntervalKey, Task, TaskId, TaxiId, Visit

T0 = 1_700_000_000.0
K = IntervalKey(480)


@pytest.fixture
def cities_by_node(redis_cluster_url: str) -> Iterator[dict[str, str]]:
    """One city name per primary node: node address -> a city whose slot that node owns."""
    client = RedisCluster.from_url(redis_cluster_url)
    try:
        found: dict[str, str] = {}
        for i in range(1000):
            name = f"city{i}"
            node = client.nodes_manager.get_node_from_slot(client.keyslot("{" + name + "}"))
            found.setdefault(node.name, name)
            if len(found) == 3:
                break
        yield found
    finally:
        client.close()


def _commit(epoch_id: str, version: int, time_s: float, nonce: str = "n-1") -> EpochCommit:
    return EpochCommit(
        epoch_id=epoch_id,
        body_hash=f"h-{epoch_id}",
        time_s=time_s,
        expected_version=version,
        visits=[Visit(TaxiId("a"), K, 3)],
        task_updates=[Task(TaskId("p1"), 1, T0, status="completed")],
        response_json="{}",
        demand_json="{}",
        demand_day="20231114",
        nonce=nonce,
    )


def test_every_node_serves_its_cities(
    make_cluster_store: Callable[[], RedisStore], cities_by_node: dict[str, str]
) -> None:
    assert len(cities_by_node) == 3, "the cluster has three primaries, each owning some cities"
    store = make_cluster_store()
    for city in cities_by_node.values():
        assert store.put_tasks(city, [Task(TaskId("p1"), 1, T0)]).created == [TaskId("p1")]
        assert store.commit_epoch(city, _commit("e1", 0, T0)).status == "committed"
        assert store.commit_epoch(city, _commit("e1", 1, T0)).status == "committed"  # its own, re-sent
        assert store.commit_epoch(city, _commit("e1", 1, T0, nonce="n-2")).status == "duplicate"
        state = store.load_state(city, [K], [TaxiId("a")])
        assert (state.version, state.counts, state.visited) == (1, {K: {3: 1}}, {TaxiId("a"): {(K, 3)}})
        assert [t.id for t in store.list_tasks(city)] == ["p1"]
        assert store.list_intervals(city) == [K]
        assert store.recorded_demand(city, "20231114") == ["{}"]
        assert store.recorded_epochs(city, ["20231114", "20231115"]) == [1, 0]
        assert store.rewind_epochs(city, T0 - 60).status == "rewound"
        assert store.reset_epochs(city) > 0 and store.load_state(city, [], []).version == 0


def test_standalone_client_on_a_cluster_node_is_told_why(
    redis_cluster_url: str, cities_by_node: dict[str, str]
) -> None:
    """A standalone store pointed at one node of a cluster cannot reach the cities of the other nodes, and
    says so (the remedy is SD_REDIS_MODE=cluster, never silence)."""
    store = RedisStore(redis_cluster_url, prefix="sdtest-standalone")
    try:
        first = redis_cluster_url.split("//", 1)[1].split("/", 1)[0]
        elsewhere = [c for node, c in cities_by_node.items() if node != first]
        with pytest.raises((redis.ResponseError, StoreUnavailable)):
            store.load_state(elsewhere[0], [K], [])
    finally:
        store.close()
