"""One way to connect to Redis for every adapter: short timeouts, one quick retry, health checks."""

from __future__ import annotations

import redis
from redis.backoff import ExponentialBackoff
from redis.retry import Retry

__all__ = ["redis_client", "describe"]


def redis_client(url: str, *, socket_timeout_s: float = 2.0) -> redis.Redis:
    """A client of ``url`` answering ``str`` (connects lazily). One quick retry covers a pooled connection
    the server dropped; no long backoff on a dead server."""
    client: redis.Redis = redis.Redis.from_url(
        url,
        decode_responses=True,
        socket_timeout=socket_timeout_s,
        socket_connect_timeout=socket_timeout_s,
        retry=Retry(ExponentialBackoff(cap=0.05, base=0.01), 1),
        health_check_interval=30,
    )
    return client


def describe(client: redis.Redis) -> str:
    """Where the client connects, for messages (never the password)."""
    kwargs = client.connection_pool.connection_kwargs
    where = kwargs.get("path") or f"{kwargs.get('host', '?')}:{kwargs.get('port', '?')}"
    return f"redis://{where}/{kwargs.get('db', 0)}"
