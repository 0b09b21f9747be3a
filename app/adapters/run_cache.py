"""Finished simulation runs in Redis, shared by every fleet worker and experiment that names the server:
``<prefix>:run:<job key>`` holds the run's JSON document (``RunResult.to_json``) and expires after
``ttl_s``. Implements ``app.runs.ResultCache``."""

from __future__ import annotations

import logging

import redis
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError

from app.adapters.redis_client import describe
from app.ports import StoreUnavailable
from app.runs import RunResult

__all__ = ["RedisRunCache"]

log = logging.getLogger(__name__)


class RedisRunCache:
    """Runs by job key in Redis; an unreadable entry counts as missing (and is logged), an unreachable
    server raises ``StoreUnavailable``."""

    def __init__(self, client: redis.Redis, prefix: str = "sd", *, ttl_s: int = 15 * 86400) -> None:
        """``client`` from ``app.adapters.redis_client.redis_client`` (it answers ``str``)."""
        if not prefix or ttl_s < 1:
            raise ValueError(f"need a prefix and a positive TTL, got {prefix!r} and {ttl_s}")
        self._client = client
        self._prefix = prefix
        self.ttl_s = ttl_s

    def _key(self, key: str) -> str:
        return f"{self._prefix}:run:{key}"

    def _unavailable(self, doing: str, exc: Exception) -> StoreUnavailable:
        return StoreUnavailable(f"Redis at {describe(self._client)} is unreachable while {doing}: {exc}")

    def get(self, key: str) -> RunResult | None:
        """The cached run, or ``None``."""
        try:
            text = self._client.get(self._key(key))
        except (RedisConnectionError, RedisTimeoutError) as exc:
            raise self._unavailable("reading a cached run", exc) from exc
        if text is None:
            return None
        try:
            return RunResult.from_json(str(text))
        except (ValueError, KeyError, TypeError) as exc:
            log.warning("ignoring unreadable cached run %s: %r", self._key(key), exc)
            return None

    def put(self, result: RunResult) -> None:
        """Store a run (one SET: readers see all of it or nothing)."""
        try:
            self._client.set(self._key(result.key), result.to_json(), ex=self.ttl_s)
        except (RedisConnectionError, RedisTimeoutError) as exc:
            raise self._unavailable("caching a run", exc) from exc
