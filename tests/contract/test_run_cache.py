"""One suite for every ``ResultCache``: the disk cache under a directory and the Redis cache every fleet
worker shares (a real ``redis-server``)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from app.adapters.redis_client import redis_client
from app.adapters.run_cache import RedisRunCache
from app.ports import StoreUnavailable
from app.runs import ResultCache, RunCache
from app.runs.localcluster import free_port
from tests.unit.test_worker_parts import result

# Writes an unreadable entry for ``key`` behind the cache's back.
Corrupt = Callable[[str], None]


@pytest.fixture(params=["disk", pytest.param("redis", marks=pytest.mark.redis)])
def cache_case(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[ResultCache, Corrupt]]:
    if request.param == "disk":
        disk = RunCache(tmp_path / "runs")

        def corrupt_file(key: str) -> None:
            disk.directory.mkdir(parents=True, exist_ok=True)
            (disk.directory / f"{key}.json").write_text('{"key": "truncated')

        yield disk, corrupt_file
        return
    url: str = request.getfixturevalue("redis_url")
    prefix: str = request.getfixturevalue("redis_prefix")
    client = redis_client(url)
    try:

        def corrupt_key(key: str) -> None:
            client.set(f"{prefix}:run:{key}", '{"key": "truncated')

        yield RedisRunCache(client, prefix, ttl_s=3600), corrupt_key
    finally:
        client.close()


def test_a_missing_run_is_none(cache_case: tuple[ResultCache, Corrupt]) -> None:
    cache, _ = cache_case
    assert cache.get("chengdu-s1-x10-nothing") is None


def test_a_run_comes_back_as_it_was_stored(cache_case: tuple[ResultCache, Corrupt]) -> None:
    cache, _ = cache_case
    r = result("chengdu-s1-x20-k", 20)
    cache.put(r)
    back = cache.get(r.key)
    assert back is not None and back.to_json() == r.to_json()
    assert math.isnan(back.kpis.completion_rate) and back.kpis.hours == r.kpis.hours and back.spec == r.spec


def test_a_later_put_replaces_the_run_and_keys_stay_apart(cache_case: tuple[ResultCache, Corrupt]) -> None:
    cache, _ = cache_case
    cache.put(result("a", 10, kpi=1.0))
    cache.put(result("b", 20, kpi=2.0))
    cache.put(result("a", 10, kpi=3.0))
    a, b = cache.get("a"), cache.get("b")
    assert a is not None and b is not None
    assert (a.kpis.design_kpi, b.kpis.design_kpi) == (3.0, 2.0)


def test_an_unreadable_entry_counts_as_missing_and_is_logged(
    cache_case: tuple[ResultCache, Corrupt], caplog: pytest.LogCaptureFixture
) -> None:
    cache, corrupt = cache_case
    corrupt("bad")
    with caplog.at_level(logging.WARNING):
        assert cache.get("bad") is None
    assert "unreadable cached run" in caplog.text
    cache.put(result("bad", 10))  # the next run replaces it
    assert cache.get("bad") is not None


def test_redis_entries_expire_and_an_unreachable_server_is_an_error(
    redis_url: str, redis_prefix: str
) -> None:
    client = redis_client(redis_url)
    try:
        cache = RedisRunCache(client, redis_prefix, ttl_s=120)
        cache.put(result("k", 10))
        assert 110 <= client.ttl(f"{redis_prefix}:run:k") <= 120
    finally:
        client.close()
    dead = redis_client(f"redis://127.0.0.1:{free_port()}/0", socket_timeout_s=0.5)
    with pytest.raises(StoreUnavailable, match="unreachable while reading a cached run"):
        RedisRunCache(dead).get("k")
    with pytest.raises(StoreUnavailable, match="unreachable while caching a run"):
        RedisRunCache(dead).put(result("k", 10))
