"""The real NYC requests of 2014-12-21 on the Manhattan network, and bootstrap days (docs/METHOD.md
section 10).

* **Day 0** is the real day: the records between the horizon's start and end (08:00-12:00 local) as they
  are -- their ids, their (whole-minute) times, origin and destination snapped to the nearest node. A
  record whose origin or destination lies farther than ``city.params.snap_limit_m`` from every node is
  dropped and counted (``params["n_dropped_off_network"]``). With ``rate_per_hour`` the day is thinned at
  random (seeded) to that rate, each hour keeping its share of the real day (largest remainders).
  ``generator="nyc-<date>"``.
* **Day d > 0** is a bootstrap resample of the real (possibly thinned) day *within each hour*: hour ``k``
  keeps its request count ``n_k`` and draws ``n_k`` of the real hour-``k`` requests with replacement; the
  request times are **re-drawn** uniformly (whole seconds) within the hour, because keeping them would
  repeat identical requests at the same second. Ids are ``b{d}-{i:05d}`` in time order.
  ``generator="nyc-bootstrap"``.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from services.city import City, Horizon
from services.sim.demand import DemandFileError, DemandSet, Request, demand_rng
from services.sim.demand_csv import read_csv_rows

__all__ = ["NYC_COLUMNS", "TripRecords", "read_nyc_requests", "manhattan_demand", "thinned_counts"]

NYC_COLUMNS = ("request_id", "o_lat", "o_lon", "d_lat", "d_lon", "departure_time")
_STREAM = 0x9C1B


@dataclass(frozen=True, slots=True, eq=False)
class TripRecords:
    """Trip records read from a file: ids, naive local departure times, origin and destination lon/lat.

    Attributes
    ----------
    source : str                   the file's name
    request_id : tuple of str      unique
    local_time : datetime64[s] (n,)  local wall-clock time (no timezone)
    o_lon, o_lat, d_lon, d_lat : float64 (n,)  WGS84 degrees
    """

    source: str
    request_id: tuple[str, ...]
    local_time: NDArray[np.datetime64]
    o_lon: NDArray[np.float64]
    o_lat: NDArray[np.float64]
    d_lon: NDArray[np.float64]
    d_lat: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.request_id)


def read_nyc_requests(path: Path | str) -> TripRecords:
    """Read the NYC request file (``nyc_20k.csv.gz`` or a plain ``.csv``).

    Columns ``request_id, o_lat, o_lon, d_lat, d_lon, departure_time`` (``YYYY-MM-DD HH:MM:SS`` local
    New York time); others (``passengers``) are ignored.

    Raises
    ------
    DemandFileError
        Naming the file and row of a missing column, a bad number or time, or a duplicate id.
    """
    path = Path(path)
    name = path.name
    _, rows = read_csv_rows(path, NYC_COLUMNS)
    ids: list[str] = []
    seen: dict[str, int] = {}
    times: list[dt.datetime] = []
    coords = np.empty((len(rows), 4), dtype=np.float64)
    for k, (row, rec) in enumerate(rows):
        rid = rec["request_id"]
        if not rid or rid in seen:
            raise DemandFileError(name, row, f"request_id {rid!r} is empty or a duplicate")
        seen[rid] = row
        ids.append(rid)
        for j, col in enumerate(("o_lon", "o_lat", "d_lon", "d_lat")):
            try:
                value = float(rec[col])
            except ValueError:
                raise DemandFileError(name, row, f"{col} must be a number, got {rec[col]!r}") from None
            if not (math.isfinite(value) and abs(value) <= (180.0 if col.endswith("lon") else 90.0)):
                raise DemandFileError(name, row, f"{col} {rec[col]} is not a WGS84 coordinate")
            coords[k, j] = value
        text = rec["departure_time"]
        try:
            when = dt.datetime.strptime(text, "%Y-%m-%d %H:%M:%S")
        except ValueError:
            raise DemandFileError(name, row, f"departure_time {text!r} is not YYYY-MM-DD HH:MM:SS") from None
        times.append(when)
    return TripRecords(
        source=name,
        request_id=tuple(ids),
        local_time=np.array(times, dtype="datetime64[s]").reshape(-1),
        o_lon=coords[:, 0].copy(),
        o_lat=coords[:, 1].copy(),
        d_lon=coords[:, 2].copy(),
        d_lat=coords[:, 3].copy(),
    )


def thinned_counts(counts: NDArray[np.int64], total: int) -> NDArray[np.int64]:
    """Split ``total`` over the intervals in proportion to ``counts`` (largest remainders; ties to the
    earlier interval), never above ``counts``.

    Raises
    ------
    ValueError
        If ``total`` exceeds ``counts.sum()`` or is negative.
    """
    counts = np.asarray(counts, dtype=np.int64)
    out: NDArray[np.int64] = counts.copy()
    have = int(counts.sum())
    if not 0 <= total <= have:
        raise ValueError(f"cannot thin {have} requests to {total}")
    if have == 0:
        return out
    share = counts * (total / have)
    out[:] = np.floor(share)
    order = np.argsort(-(share - out), kind="stable")
    out[order[: total - int(out.sum())]] += 1
    return out


@dataclass(frozen=True, slots=True, eq=False)
class _Snapped:
    """The records inside a day's horizon whose origin and destination snap onto the network.

    Attributes
    ----------
    idx : int64 (k,)              their positions in the records
    o_nodes, d_nodes : int64 (k,)  origin and destination nodes
    times : float64 (k,)          POSIX seconds (whole)
    interval : int64 (k,)         the horizon's interval each falls in
    start_s : float               POSIX seconds of the horizon's start
    n_in_horizon : int            records inside the horizon, those off the network included
    n_dropped : int               records inside the horizon but off the network
    """

    idx: NDArray[np.int64]
    o_nodes: NDArray[np.int64]
    d_nodes: NDArray[np.int64]
    times: NDArray[np.float64]
    interval: NDArray[np.int64]
    start_s: float
    n_in_horizon: int
    n_dropped: int


def _snapped(city: City, records: TripRecords, date: str) -> _Snapped:
    """The records of ``date``'s horizon on the city's network (those farther than the snap limit
    dropped)."""
    hz = city.horizon
    local_start = np.datetime64(dt.datetime.combine(dt.date.fromisoformat(date), hz.start), "s")
    offset = (records.local_time - local_start).astype(np.int64)  # seconds after the local start
    inside = (offset >= 0) & (offset < hz.length_s)
    idx = np.flatnonzero(inside)
    if idx.size == 0:
        raise ValueError(f"no {records.source} record between {date} {hz.start:%H:%M} and the horizon's end")
    net, limit = city.network, city.params.snap_limit_m
    o_nodes, o_dist = net.snap_many(records.o_lon[idx], records.o_lat[idx], np.inf)
    d_nodes, d_dist = net.snap_many(records.d_lon[idx], records.d_lat[idx], np.inf)
    on_net = (o_dist <= limit) & (d_dist <= limit)
    idx, o_nodes, d_nodes = idx[on_net], o_nodes[on_net], d_nodes[on_net]
    # whole POSIX seconds at the UTC offset of the horizon start (clock changes happen at night)
    start_s = hz.start_s(date)
    return _Snapped(
        idx=idx,
        o_nodes=o_nodes,
        d_nodes=d_nodes,
        times=np.asarray(start_s + offset[idx], dtype=np.float64),
        interval=offset[idx] // hz.interval_s,
        start_s=start_s,
        n_in_horizon=int(inside.sum()),
        n_dropped=int((~on_net).sum()),
    )


def _drawn(
    rng: np.random.Generator | None, day: int, real: _Snapped, counts: NDArray[np.int64], horizon: Horizon
) -> tuple[NDArray[np.int64], NDArray[np.float64] | None]:
    """The records each interval keeps (positions in ``real``): all of them without ``rng``, ``counts[k]``
    without replacement on day 0, with replacement on a bootstrap day; and a bootstrap day's re-drawn
    times (None on day 0)."""
    chosen: list[NDArray[np.int64]] = []
    new_times: list[NDArray[np.float64]] = []
    for k in range(horizon.n_intervals):
        pool = np.flatnonzero(real.interval == k)
        if rng is None:  # the real day as it is
            chosen.append(pool)
        elif day == 0:
            chosen.append(np.sort(rng.choice(pool, int(counts[k]), replace=False)))
        else:
            chosen.append(rng.choice(pool, int(counts[k]), replace=True))
            offsets = rng.integers(0, horizon.interval_s, int(counts[k])).astype(np.float64)
            new_times.append(real.start_s + k * horizon.interval_s + offsets)
    sel = np.concatenate(chosen).astype(np.int64)
    return sel, (np.concatenate(new_times) if day > 0 else None)


def manhattan_demand(
    city: City,
    records: TripRecords,
    *,
    seed: int | None = None,
    day: int = 0,
    rate_per_hour: float | None = None,
    date: str = "2014-12-21",
) -> DemandSet:
    """The real day (``day=0``) or a bootstrap day (``day > 0``) of NYC requests (module docstring).

    Parameters
    ----------
    city : City
        The Manhattan city (its network, snap limit, timezone and horizon).
    records : TripRecords
        From :func:`read_nyc_requests`.
    seed : int, optional
        Needed when thinning or bootstrapping; with ``day`` it fixes the draws.
    day : int
        0 for the real day, ``d > 0`` for bootstrap day ``d``.
    rate_per_hour : float, optional
        Thin to ``round(rate_per_hour * horizon hours)`` requests (e.g. 144 for the paper's setting).
    date : str
        The local date whose horizon is taken from the records; also the set's date.

    Raises
    ------
    ValueError
        If no record falls in the horizon, the rate exceeds the real one, or a seed is needed and missing.
    """
    if isinstance(day, bool) or not isinstance(day, int) or day < 0:
        raise ValueError(f"day must be a non-negative integer, got {day!r}")
    if (day > 0 or rate_per_hour is not None) and seed is None:
        raise ValueError("a seed is needed to thin or bootstrap the NYC day")
    hz = city.horizon
    real = _snapped(city, records, date)
    real_counts = np.bincount(real.interval, minlength=hz.n_intervals).astype(np.int64)
    params: dict[str, Any] = {
        "source": records.source,
        "day": int(day),
        "n_in_horizon": real.n_in_horizon,
        "n_dropped_off_network": real.n_dropped,
        "snap_limit_m": float(city.params.snap_limit_m),
        "real_per_interval": real_counts.tolist(),
        "rate_per_hour": None if rate_per_hour is None else float(rate_per_hour),
    }
    counts = real_counts
    rng = None if seed is None else np.random.default_rng(demand_rng(_STREAM, seed, day))
    if rate_per_hour is not None:
        if not (math.isfinite(rate_per_hour) and rate_per_hour >= 0):
            raise ValueError("rate_per_hour must be a non-negative number")
        counts = thinned_counts(real_counts, round(rate_per_hour * hz.length_s / 3600.0))
    params["per_interval"] = counts.tolist()

    sel, t_all = _drawn(rng, day, real, counts, hz)
    if t_all is None:
        requests = [
            Request(
                records.request_id[real.idx[j]],
                float(real.times[j]),
                int(real.o_nodes[j]),
                int(real.d_nodes[j]),
            )
            for j in sel
        ]
        requests.sort(key=lambda r: (r.time_s, r.id))
        return DemandSet(city.name, date, tuple(requests), f"nyc-{date}", seed=seed, params=params)
    order = np.argsort(t_all, kind="stable")
    params["times"] = "re-drawn uniformly within the hour"
    requests = [
        Request(f"b{day}-{i:05d}", float(t_all[j]), int(real.o_nodes[sel[j]]), int(real.d_nodes[sel[j]]))
        for i, j in enumerate(order)
    ]
    return DemandSet(city.name, date, tuple(requests), "nyc-bootstrap", seed=seed, params=params)
