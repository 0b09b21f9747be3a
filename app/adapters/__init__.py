"""Store adapters implementing ``app.ports.Store``: ``MemoryStore`` (embedded default), ``RedisStore``."""

from app.adapters.memory_store import MemoryStore
from app.adapters.redis_store import RedisStore

__all__ = ["MemoryStore", "RedisStore"]
