"""The coverage use case: a sensing interval's grid counts Lambda, its coverage rate and Gamma over the day
so far (the paper's coverage measures; docs/METHOD.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.errors import NoData
from app.ports import EpochStore
from app.usecases.cities import CityCatalog
from services.city import City
from services.ledger import dense_counts
from services.model import IntervalKey
from services.sensing.sensing import coverage_rate, gamma

__all__ = ["Coverage", "CoverageService"]


@dataclass(frozen=True, slots=True)
class Coverage:
    """The grid counts of one sensing interval: ``counts`` is Lambda over every cell; ``gamma_so_far`` is
    Gamma over that day's horizon intervals as counted so far."""

    city: City
    interval: IntervalKey
    counts: NDArray[np.int64]
    coverage_rate: float
    gamma_so_far: float


class CoverageService:
    """Reads the counted visits of a city's sensing intervals."""

    def __init__(self, cities: CityCatalog, store: EpochStore) -> None:
        self.cities = cities
        self.store = store

    def coverage(self, name: str, interval: IntervalKey | None) -> Coverage:
        """Lambda per cell, coverage rate and Gamma so far for one interval (default: the last epoch's)."""
        city = self.cities.get(name)
        if interval is not None:
            k = interval
        else:
            state = self.store.load_state(name, [], [])
            if state.last_epoch_time_s is None:
                raise NoData(f"no epoch committed for {name!r} yet; pass ?interval=")
            k = city.horizon.interval_of(state.last_epoch_time_s)
        day = city.horizon.day_intervals(k)
        wanted = sorted(set(day) | {k})
        counts = {j: dense_counts(self.store.interval_counts(name, j), city.grid.n_cells) for j in wanted}
        return Coverage(city, k, counts[k], coverage_rate(city, counts[k]), gamma(city, counts, day))
