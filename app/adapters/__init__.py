"""Adapters: the stores implementing ``app.ports.Store`` (``MemoryStore``, the embedded default, and
``RedisStore``) and the city registry over bundles on disk (``app.adapters.city_registry``, the use cases'
``CityCatalog``)."""

from app.adapters.memory_store import MemoryStore
from app.adapters.redis_store import RedisStore

__all__ = ["MemoryStore", "RedisStore"]
