"""The ``store`` fixture: every contract test runs once per ``Store`` implementation."""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass

import pytest
import redis

from app.adapters import MemoryStore, RedisStore
from app.ports import Store


@dataclass(frozen=True)
class StoreCase:
    """A store under test and a way to capture its raw state (every Redis key, or the memory internals)."""

    store: Store
    raw: Callable[[], object]


def redis_dump(url: str, prefix: str) -> dict[str, object]:
    """Every key under ``prefix:`` with its type and value (TTLs left out)."""
    client = redis.Redis.from_url(url, decode_responses=True)
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


@pytest.fixture(params=["memory", pytest.param("redis", marks=pytest.mark.redis)])
def make_case(request: pytest.FixtureRequest) -> Callable[[], StoreCase]:
    """Factory of fresh, empty stores of one kind (a new key prefix per Redis store)."""
    if request.param == "memory":

        def make_memory() -> StoreCase:
            store = MemoryStore()
            return StoreCase(store, lambda: copy.deepcopy(store._cities))

        return make_memory

    make_redis: Callable[[], RedisStore] = request.getfixturevalue("make_redis_store")
    url: str = request.getfixturevalue("redis_url")

    def make_redis_case() -> StoreCase:
        store = make_redis()
        return StoreCase(store, lambda: redis_dump(url, store.prefix))

    return make_redis_case


@pytest.fixture
def case(make_case: Callable[[], StoreCase]) -> StoreCase:
    """One fresh store with its raw-state probe."""
    return make_case()


@pytest.fixture
def store(case: StoreCase) -> Store:
    """One fresh store."""
    return case.store
