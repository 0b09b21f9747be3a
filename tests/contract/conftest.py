"""The ``store`` fixture: every contract test runs once per ``Store`` implementation."""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
import redis

from app.adapters import MemoryStore, RedisStore
from app.ports import Store


@dataclass(frozen=True)
class StoreCase:
    """A store under test, a way to capture its raw state (every Redis key, or the memory internals) and a
    factory of other store objects on the same data (for Redis each with its own connections, like another
    process; for memory the same object)."""

    store: Store
    raw: Callable[[], object]
    again: Callable[[], Store]


def redis_dump(url: str, prefix: str, *, cluster: bool = False) -> dict[str, object]:
    """Every key under ``prefix:`` with its type and value (TTLs left out)."""
    from redis.cluster import RedisCluster

    client: Any = (
        RedisCluster.from_url(url, decode_responses=True)
        if cluster
        else redis.Redis.from_url(url, decode_responses=True)
    )
    try:
        out: dict[str, object] = {}
        for key in sorted(client.scan_iter(match=f"{prefix}:*", count=1000)):
            kind = client.type(key)
            if kind == "hash":
                out[key] = ("hash", client.hgetall(key))
            elif kind == "set":
                out[key] = ("set", client.smembers(key))
            elif kind == "zset":
                out[key] = ("zset", client.zrange(key, 0, -1, withscores=True))
            elif kind == "list":
                out[key] = ("list", client.lrange(key, 0, -1))
            else:
                out[key] = (kind, client.dump(key))
        return out
    finally:
        client.close()


@pytest.fixture(
    params=[
        "memory",
        pytest.param("redis", marks=pytest.mark.redis),
        pytest.param("redis-cluster", marks=pytest.mark.redis),
    ]
)
def make_case(request: pytest.FixtureRequest) -> Iterator[Callable[[], StoreCase]]:
    """Factory of fresh, empty stores of one kind (a new key prefix per Redis store; ``redis-cluster``: a
    cluster-mode store on a real 3-master cluster)."""
    if request.param == "memory":

        def make_memory() -> StoreCase:
            store = MemoryStore()
            return StoreCase(store, lambda: copy.deepcopy(store._cities), lambda: store)

        yield make_memory
        return

    cluster = request.param == "redis-cluster"
    make_redis: Callable[[], RedisStore] = request.getfixturevalue(
        "make_cluster_store" if cluster else "make_redis_store"
    )
    url: str = request.getfixturevalue("redis_cluster_url" if cluster else "redis_url")
    others: list[RedisStore] = []

    def make_redis_case() -> StoreCase:
        store = make_redis()

        def again() -> Store:
            others.append(RedisStore(url, prefix=store.prefix, mode=store.mode))
            return others[-1]

        return StoreCase(store, lambda: redis_dump(url, store.prefix, cluster=cluster), again)

    yield make_redis_case
    for other in others:
        other.close()


@pytest.fixture
def case(make_case: Callable[[], StoreCase]) -> StoreCase:
    """One fresh store with its raw-state probe."""
    return make_case()


@pytest.fixture
def store(case: StoreCase) -> Store:
    """One fresh store."""
    return case.store
