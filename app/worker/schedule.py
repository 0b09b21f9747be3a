"""When the worker solves: the coming hour of a city's horizon and whether it is due (city local time)."""

from __future__ import annotations

from services.city import Horizon
from services.model import IntervalKey

__all__ = ["coming_interval", "due_interval"]


def coming_interval(horizon: Horizon, now_s: float) -> IntervalKey:
    """The hour a solve at ``now_s`` is for (``Horizon.coming_interval``)."""
    return horizon.coming_interval(now_s)


def due_interval(horizon: Horizon, now_s: float, lead_s: float) -> IntervalKey | None:
    """The coming interval if it starts within ``lead_s`` of ``now_s`` (its solve is due), else ``None``.

    With the default lead of one interval the hour ``h`` is solved from the start of hour ``h - 1``: at
    07:00 for 08:00, at 08:00 for 09:00, ..., and nothing between the end of the horizon and the hour
    before the next day's first interval.
    """
    k = coming_interval(horizon, now_s)
    return k if horizon.interval_start_s(k) - now_s <= lead_s else None
