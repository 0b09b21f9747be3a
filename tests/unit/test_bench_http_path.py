"""A smoke run of the HTTP path's stage benchmark (``bench/bench_http_path.py``) on both stores: every stage
is timed on every epoch, the stages add up to the whole, and the Redis run leaves no key behind."""

from __future__ import annotations

import gc

import pytest
import redis

from app.api.warmup import GC_THRESHOLD
from bench import bench_http_path


def _check(res: dict[str, object], store: str) -> None:
    med = res["median_ms"]
    assert isinstance(med, dict) and set(med) == {*bench_http_path.STAGES, "total"}
    assert res["store"] == store and res["epochs"] == 2
    # every stage was timed inside the epoch's whole, and the rest of the use case is what is left of it
    assert all(med[k] > 0 for k in bench_http_path.STAGES if k != "other") and med["other"] >= 0
    besides = res["besides_decide_ms"]
    assert isinstance(besides, float) and 0 < besides < med["total"]


def test_the_stages_on_the_memory_store() -> None:
    thresholds = gc.get_threshold()
    res = bench_http_path.run("paper", 2, profile=True)
    _check(res, "memory")
    assert "function calls" in str(res["profile"])
    assert gc.get_threshold() == GC_THRESHOLD and gc.isenabled()
    gc.set_threshold(*thresholds)


@pytest.mark.redis
def test_the_stages_on_redis(redis_url: str) -> None:
    thresholds = gc.get_threshold()
    before = set(redis.Redis.from_url(redis_url).scan_iter(match="benchpath*"))
    _check(bench_http_path.run("paper", 2, redis_url), "redis")
    gc.set_threshold(*thresholds)
    assert set(redis.Redis.from_url(redis_url).scan_iter(match="benchpath*")) == before
