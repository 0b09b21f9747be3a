"""The readiness use case: whether this instance can take epochs (``GET /readyz``)."""

from __future__ import annotations

import threading

from app.errors import Unavailable
from app.ports import EpochStore
from app.usecases.cities import CityCatalog

__all__ = ["ReadinessService"]


class ReadinessService:
    """Answers whether the store, the warm-up and every city are ready."""

    def __init__(self, cities: CityCatalog, store: EpochStore) -> None:
        self.cities = cities
        self.store = store
        self.warming: threading.Event | None = None
        """Set by the app's start-up: unset while the cities are being warmed up (``ready`` is 503)."""

    def ready(self) -> list[str]:
        """The served cities once the store answers, the start-up warm-up (``warming``) has finished and every
        city loads (``Unavailable``, a 503, else)."""
        if self.warming is not None and not self.warming.is_set():
            raise Unavailable(
                "warming up: the cities are loading and the routing kernels compiling (minutes on a fresh "
                "install, under a second once they are cached); epochs posted now wait for it"
            )
        self.store.ping()
        names = self.cities.names()
        if not names:
            raise Unavailable("no cities are installed")
        for name in names:
            try:
                self.cities.get(name)
            except Exception as exc:  # a broken city bundle makes the instance not ready, not crashed
                raise Unavailable(f"city {name!r} failed to load: {exc}") from exc
        return names
