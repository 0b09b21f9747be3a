"""The admin use cases: rewind a city's epoch stream to an earlier time, or reset it (docs/DESIGN.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from app.errors import InvalidInput, NoData
from app.ports import RewindResult, StreamStore
from app.usecases.cities import CityCatalog
from services.city import City
from services.rfc3339 import format_time

__all__ = ["AdminService", "StreamChange"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class StreamChange:
    """What a rewind or a reset did to a city's epoch stream (times are POSIX seconds, None when unset)."""

    city: City
    action: str
    previous_time_s: float | None
    time_s: float | None
    committed: int
    deleted: int


class AdminService:
    """Rewinds and resets epoch streams."""

    def __init__(self, cities: CityCatalog, store: StreamStore) -> None:
        self.cities = cities
        self.store = store

    def rewind(self, name: str, time_s: float) -> StreamChange:
        """Set the city's last epoch time back to ``time_s`` (404 ``no_data`` with no epoch committed; 422
        on ``to`` when it is later than the last epoch time)."""
        city = self.cities.get(name)
        result: RewindResult = self.store.rewind_epochs(name, time_s)
        if result.status == "empty":
            raise NoData(f"no epoch committed for {name!r}: nothing to rewind")
        if result.status == "ahead":
            assert result.previous_time_s is not None
            last = format_time(result.previous_time_s, city.horizon.timezone)
            raise InvalidInput.at("to", f"later than the last epoch time {last}: nothing to rewind")
        log.warning("epoch stream of %s rewound from %s to %s", name, result.previous_time_s, time_s)
        return StreamChange(city, "rewind", result.previous_time_s, time_s, result.version, 0)

    def reset(self, name: str) -> StreamChange:
        """Delete the city's epoch stream and tasks (fleet records stay)."""
        city = self.cities.get(name)
        before = self.store.load_state(name, [], [])
        deleted = self.store.reset_epochs(name)
        log.warning("epoch stream of %s reset: %d entries deleted", name, deleted)
        return StreamChange(city, "reset", before.last_epoch_time_s, None, 0, deleted)
