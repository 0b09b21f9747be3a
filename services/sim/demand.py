"""Demand sets: synthetic Chengdu requests, the real NYC day, and user CSV files (docs/METHOD.md section 10).

Every set records its generator, version and seed so a run can be reproduced exactly. Request times are
whole POSIX seconds (they travel through RFC 3339 text without rounding).

The generators live in topical modules next to this one:

* :mod:`services.sim.demand_chengdu` -- ``chengdu_demand``, ``poi_density``, ``read_pois_csv``;
* :mod:`services.sim.demand_nyc` -- ``read_nyc_requests``, ``manhattan_demand``;
* :mod:`services.sim.demand_csv` -- ``read_demand_csv``, ``write_demand_csv``.

This module holds the types they share, the file error and the JSON form of a set
(:func:`demand_to_json`, :func:`demand_from_json`) for recording a set next to experiment results.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from services.city import City, Horizon

__all__ = [
    "DEMAND_VERSION",
    "Request",
    "DemandSet",
    "DemandFileError",
    "demand_rng",
    "demand_on_date",
    "demand_to_json",
    "demand_from_json",
]

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

    def counts_per_interval(self, start_s: float, interval_s: int, n_intervals: int) -> list[int]:
        """Requests in each of ``n_intervals`` intervals of ``interval_s`` from POSIX time ``start_s``.

        Requests outside ``[start_s, start_s + n_intervals * interval_s)`` are not counted.
        """
        counts = [0] * n_intervals
        for r in self.requests:
            k = math.floor((r.time_s - start_s) / interval_s)
            if 0 <= k < n_intervals:
                counts[k] += 1
        return counts


def demand_on_date(demand: DemandSet, horizon: Horizon, date: str) -> DemandSet:
    """The same requests on local date ``date`` (``YYYY-MM-DD``): each keeps its time from the start of the
    horizon (so a replay can run on a day the service holds no epochs of yet)."""
    shift_s = horizon.start_s(date) - horizon.start_s(demand.date)
    moved = tuple(Request(r.id, r.time_s + shift_s, r.origin, r.destination) for r in demand.requests)
    return dataclasses.replace(demand, date=date, requests=moved)


class DemandFileError(ValueError):
    """A demand file (or JSON record) is malformed.

    Parameters
    ----------
    file : str
        The file's name (or path).
    row : int or None
        1-based data row (header excluded); None for whole-file problems.
    problem : str
        What is wrong.
    """

    def __init__(self, file: str, row: int | None, problem: str) -> None:
        self.file = file
        self.row = row
        self.problem = problem
        where = f"{file}, row {row}" if row is not None else file
        super().__init__(f"{where}: {problem}")


def demand_rng(stream: int, seed: int, day: int, *extra: int) -> np.random.SeedSequence:
    """The seed sequence of one generator's day: ``SeedSequence(seed, spawn_key=(stream, day, *extra))``.

    ``stream`` keeps generators apart (two generators given the same seed and day draw independent
    numbers); callers spawn one child per quantity they draw so that changing one parameter does not shift
    the draws of the others.

    Raises
    ------
    ValueError
        If ``seed`` or ``day`` is negative or not an integer.
    """
    for name, value in (("seed", seed), ("day", day)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    return np.random.SeedSequence(int(seed), spawn_key=(stream, int(day), *extra))


def demand_to_json(demand: DemandSet, city: City) -> dict[str, Any]:
    """The set as a JSON-ready dict: its manifest and one ``[id, time_s, origin_id, destination_id]`` row
    per request, node ids being the network's external ids (stable across rebuilds of the bundle).

    Parameters
    ----------
    demand : DemandSet
    city : City
        The city whose network the set's node indices refer to.
    """
    if demand.city != city.name:
        raise ValueError(f"the set is for city {demand.city!r}, not {city.name!r}")
    ids = city.network.node_ids
    return {
        "manifest": demand.manifest(),
        "columns": ["request_id", "time_s", "origin_node", "destination_node"],
        "requests": [
            [r.id, int(r.time_s), int(ids[r.origin]), int(ids[r.destination])] for r in demand.requests
        ],
    }


def demand_from_json(obj: Any, city: City, *, name: str = "demand.json") -> DemandSet:
    """Inverse of :func:`demand_to_json`: ``demand_from_json(demand_to_json(d, city), city) == d`` when
    ``d.params`` holds JSON values only (the generators here store lists, not tuples).

    Raises
    ------
    DemandFileError
        Naming ``name`` and the request row (1-based) when the record is malformed or a node id is unknown.
    """
    try:
        man = obj["manifest"]
        rows = obj["requests"]
        date, gen, version = str(man["date"]), str(man["generator"]), str(man["version"])
        seed = man["seed"]
        params = dict(man["params"])
        city_name = str(man["city"])
    except (KeyError, TypeError) as exc:
        raise DemandFileError(name, None, f"not a demand record (missing {exc})") from None
    if city_name != city.name:
        raise DemandFileError(name, None, f"the set is for city {city_name!r}, not {city.name!r}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise DemandFileError(name, None, f"seed must be an integer or null, got {seed!r}")
    requests: list[Request] = []
    seen: set[str] = set()
    for i, row in enumerate(rows, start=1):
        try:
            rid, time_s, o_id, d_id = row
        except (TypeError, ValueError):
            problem = f"expected [id, time_s, origin, destination], got {row!r}"
            raise DemandFileError(name, i, problem) from None
        if not isinstance(rid, str) or not rid or rid in seen:
            raise DemandFileError(name, i, f"request id {rid!r} is empty, not a string or a duplicate")
        if isinstance(time_s, bool) or not isinstance(time_s, int):
            raise DemandFileError(name, i, f"time_s must be whole seconds, got {time_s!r}")
        try:
            o, d = city.network.index_of(o_id), city.network.index_of(d_id)
        except ValueError as exc:
            raise DemandFileError(name, i, str(exc)) from None
        seen.add(rid)
        requests.append(Request(rid, float(time_s), o, d))
    if len(requests) != man.get("n_requests", len(requests)):
        problem = f"the manifest says {man['n_requests']} requests, found {len(requests)}"
        raise DemandFileError(name, None, problem)
    requests.sort(key=lambda r: (r.time_s, r.id))
    return DemandSet(city_name, date, tuple(requests), gen, version, seed, params)
