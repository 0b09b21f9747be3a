"""Demand sets: synthetic Chengdu requests, the real NYC day, and user CSV files (METHOD section 10).

Every set records its generator, version and seed so a run can be reproduced exactly. Request times are
whole POSIX seconds (they travel through RFC 3339 text without rounding).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["DEMAND_VERSION", "Request", "DemandSet"]

DEMAND_VERSION = "1"


@dataclass(frozen=True, slots=True)
class Request:
    """One trip request: id, request time (whole POSIX seconds), origin and destination node indices."""

    id: str
    time_s: float
    origin: int
    destination: int


@dataclass(frozen=True, slots=True)
class DemandSet:
    """The requests of one operating day (sorted by time, then id) and how they were made."""

    city: str
    date: str  # local calendar date of the horizon, YYYY-MM-DD
    requests: tuple[Request, ...]
    generator: str  # e.g. "chengdu-synthetic", "nyc-2014-12-21", "nyc-bootstrap", "csv"
    version: str = DEMAND_VERSION
    seed: int | None = None
    params: Mapping[str, Any] = field(default_factory=dict)

    def manifest(self) -> dict[str, Any]:
        """JSON-ready description (no requests): what made this set."""
        return {
            "city": self.city,
            "date": self.date,
            "n_requests": len(self.requests),
            "generator": self.generator,
            "version": self.version,
            "seed": self.seed,
            "params": dict(self.params),
        }
