"""Demand sets from and to CSV files (docs/METHOD.md section 10: user demand next to the generated sets).

File format (UTF-8, one header line, one request per row; columns in any order, extra columns ignored
and listed in ``params["ignored_columns"]``):

``request_id,time,origin_node,destination_node``
    node ids are the network's *external* ids (OSM ids for the bundled cities);
``request_id,time,origin_lon,origin_lat,destination_lon,destination_lat``
    WGS84 degrees, snapped to the nearest node within ``city.params.snap_limit_m`` (docs/METHOD.md section 2).

``time`` is RFC 3339 with an offset (``2016-11-02T08:05:00+08:00``, ``...Z``) or local wall time in the
city's timezone without one (``2016-11-02 08:05:00``, a ``T`` also accepted), whole seconds (fractions
must be zero). A local time that a daylight-saving change skips is an error; one it repeats means its
first occurrence. Every request must lie in the city's horizon of the set's date (the ``date`` argument,
or the local date of the first data row): a time outside it is usually a timezone mistake.

A request whose origin and destination are the same node is **allowed**: a real short trip can snap to
one node, and dispatch handles a zero-length trip (pickup and drop-off at the node). Ids must be unique
and non-empty. Every problem raises :class:`~services.sim.demand.DemandFileError` naming the file, the
row (1-based, header excluded) and what is wrong.

:func:`write_demand_csv` writes the node-id format with RFC 3339 times at the city's UTC offset, so
``read_demand_csv(city, p, date=d.date).requests == d.requests`` after ``write_demand_csv(d, city, p)``
(the generator's manifest does not travel in the CSV; keep :func:`~services.sim.demand.demand_to_json`
for that).
"""

from __future__ import annotations

import csv
import datetime as dt
import gzip
import io
import math
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any
from zoneinfo import ZoneInfo

import numpy as np

from services.city import City
from services.sim.demand import DemandFileError, DemandSet, Request

__all__ = ["NODE_COLUMNS", "LONLAT_COLUMNS", "read_csv_rows", "read_demand_csv", "write_demand_csv"]

NODE_COLUMNS = ("request_id", "time", "origin_node", "destination_node")
LONLAT_COLUMNS = ("request_id", "time", "origin_lon", "origin_lat", "destination_lon", "destination_lat")

_TIME = re.compile(
    r"(\d{4}-\d{2}-\d{2})[T ](\d{2}:\d{2}:\d{2})(?:\.(\d+))?(Z|[+-]\d{2}:\d{2})?", flags=re.IGNORECASE
)
_INT = re.compile(r"[+-]?\d+")


_Rows = list[tuple[int, dict[str, str]]]
"""``(row number, {column: stripped text})`` of a file's data rows."""


@contextmanager
def _open_text(path: Path) -> Iterator[IO[str]]:
    """A text stream of a plain or gzip-compressed (``.gz``) UTF-8 file."""
    if path.suffix == ".gz":
        with gzip.open(path, "rb") as raw, io.TextIOWrapper(raw, encoding="utf-8-sig", newline="") as f:
            yield f
    else:
        with path.open(encoding="utf-8-sig", newline="") as f:
            yield f


def read_csv_rows(path: Path | str, required: Sequence[str]) -> tuple[list[str], _Rows]:
    """Header and ``(row number, {column: stripped text})`` of every non-blank data row of a CSV file.

    Plain or gzip-compressed (name ending ``.gz``). Rows are numbered from 1 after the header.

    Raises
    ------
    DemandFileError
        Unreadable file, no header, a duplicate or missing ``required`` column, or a row with the wrong
        number of fields.
    """
    path = Path(path)
    name = path.name
    rows: _Rows = []
    header: list[str] | None = None
    try:
        with _open_text(path) as f:
            reader = csv.reader(f)
            for fields in reader:
                if not fields or all(not c.strip() for c in fields):
                    continue
                if header is None:
                    header = [c.strip() for c in fields]
                    first = reader.line_num
                    dup = sorted({c for c in header if header.count(c) > 1})
                    if dup:
                        raise DemandFileError(
                            name, None, f"duplicate column(s) {', '.join(dup)} in the header"
                        )
                    missing = [c for c in required if c not in header]
                    if missing:
                        raise DemandFileError(name, None, f"missing column(s) {', '.join(missing)}")
                    continue
                row = reader.line_num - first
                if len(fields) != len(header):
                    raise DemandFileError(name, row, f"expected {len(header)} fields, found {len(fields)}")
                rows.append((row, {c: v.strip() for c, v in zip(header, fields, strict=True)}))
    except OSError as exc:
        raise DemandFileError(name, None, f"cannot read: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error, EOFError) as exc:
        raise DemandFileError(name, None, f"not a UTF-8 CSV file ({exc})") from None
    if header is None:
        raise DemandFileError(name, None, "empty file (expected a header line)")
    return header, rows


def _parse_time(name: str, row: int, text: str, tz: ZoneInfo) -> tuple[int, dt.date]:
    """POSIX seconds and local calendar date of an RFC 3339 or local ``YYYY-MM-DD HH:MM:SS`` time."""
    m = _TIME.fullmatch(text)
    if m is None:
        raise DemandFileError(
            name, row, f"time {text!r} is not RFC 3339 (2016-11-02T08:05:00+08:00) or YYYY-MM-DD HH:MM:SS"
        )
    day, clock, frac, offset = m.groups()
    if frac is not None and frac.strip("0"):
        raise DemandFileError(name, row, f"time {text!r} must be whole seconds")
    try:
        naive = dt.datetime.fromisoformat(f"{day}T{clock}")
        if offset is None:
            local = naive.replace(tzinfo=tz)
            utc = local.astimezone(dt.UTC)
            if utc.astimezone(tz).replace(tzinfo=None) != naive:
                raise DemandFileError(
                    name, row, f"local time {text!r} does not exist in {tz.key} (clock change)"
                )
        else:
            zone = dt.UTC if offset.upper() == "Z" else dt.datetime.strptime(offset, "%z").tzinfo
            utc = naive.replace(tzinfo=zone).astimezone(dt.UTC)
    except DemandFileError:
        raise
    except ValueError as exc:
        raise DemandFileError(name, row, f"time {text!r}: {exc}") from None
    return int(utc.timestamp()), utc.astimezone(tz).date()


def _node(name: str, row: int, col: str, text: str, city: City) -> int:
    if not _INT.fullmatch(text):
        raise DemandFileError(name, row, f"{col} must be an integer node id, got {text!r}")
    try:
        return city.network.index_of(int(text))
    except ValueError:
        raise DemandFileError(name, row, f"{col} {text} is not a node of the {city.name} network") from None


def _coord(name: str, row: int, col: str, text: str, bound: float) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DemandFileError(name, row, f"{col} must be a number, got {text!r}") from None
    if not (math.isfinite(value) and abs(value) <= bound):
        raise DemandFileError(name, row, f"{col} {text} is not a WGS84 coordinate")
    return value


def _columns(name: str, header: list[str]) -> tuple[str, ...]:
    """The file's format from its header: :data:`NODE_COLUMNS` or :data:`LONLAT_COLUMNS`."""
    has_node = any(c in header for c in NODE_COLUMNS[2:])
    has_lonlat = any(c in header for c in LONLAT_COLUMNS[2:])
    if has_node and has_lonlat:
        raise DemandFileError(name, None, "give origin/destination as node ids or as lon/lat, not both")
    columns = NODE_COLUMNS if has_node or not has_lonlat else LONLAT_COLUMNS
    missing = [c for c in columns if c not in header]
    if missing:
        raise DemandFileError(name, None, f"missing column(s) {', '.join(missing)}")
    return columns


def _set_date(name: str, rows: _Rows, date: str | None, tz: ZoneInfo) -> dt.date:
    """The set's local date: ``date`` when given, else the local date of the first data row's time."""
    if date is not None:
        return dt.date.fromisoformat(date)
    if rows:
        return _parse_time(name, rows[0][0], rows[0][1]["time"], tz)[1]
    raise DemandFileError(name, None, "no data rows, and no date given")


def _read_rows(
    name: str, rows: _Rows, columns: tuple[str, ...], city: City, set_date: dt.date
) -> tuple[list[int], list[tuple[Any, ...]]]:
    """Every row's time (POSIX seconds, inside the horizon of ``set_date``) and its two ends (node indices,
    or origin and destination lon/lat), ids checked unique and non-empty."""
    hz = city.horizon
    tz = ZoneInfo(hz.timezone)
    start_s = hz.start_s(set_date)
    end_s = start_s + hz.length_s
    first_row: dict[str, int] = {}
    times: list[int] = []
    ends: list[tuple[Any, ...]] = []
    for row, rec in rows:
        rid = rec["request_id"]
        if not rid:
            raise DemandFileError(name, row, "empty request_id")
        if rid in first_row:
            raise DemandFileError(name, row, f"duplicate request_id {rid!r} (first at row {first_row[rid]})")
        first_row[rid] = row
        t, _ = _parse_time(name, row, rec["time"], tz)
        if not start_s <= t < end_s:
            window = f"{set_date} {hz.start:%H:%M} + {hz.length_s // 3600} h {hz.timezone}"
            raise DemandFileError(name, row, f"time {rec['time']!r} is outside the horizon ({window})")
        times.append(t)
        if columns is NODE_COLUMNS:
            ends.append(tuple(_node(name, row, c, rec[c], city) for c in NODE_COLUMNS[2:]))
        else:
            ends.append(
                tuple(
                    _coord(name, row, c, rec[c], 180.0 if c.endswith("lon") else 90.0)
                    for c in LONLAT_COLUMNS[2:]
                )
            )
    return times, ends


def _snapped_ends(
    name: str, rows: _Rows, ends: list[tuple[Any, ...]], city: City
) -> tuple[list[int], list[int], dict[str, float]]:
    """The origin and destination nodes of lon/lat ends, each within the city's snap limit, and the limit
    and the largest snap distance for the set's params."""
    limit = city.params.snap_limit_m
    arr = np.array(ends, dtype=np.float64).reshape(-1, 4)
    o_nodes, o_dist = city.network.snap_many(arr[:, 0], arr[:, 1], np.inf)
    d_nodes, d_dist = city.network.snap_many(arr[:, 2], arr[:, 3], np.inf)
    for k, (row, _) in enumerate(rows):
        for which, dist in (("origin", o_dist[k]), ("destination", d_dist[k])):
            if dist > limit:
                raise DemandFileError(
                    name, row, f"{which} is {dist:.0f} m from the nearest node (limit {limit:.0f} m)"
                )
    max_snap_m = float(max(o_dist.max(initial=0.0), d_dist.max(initial=0.0)))
    return o_nodes.tolist(), d_nodes.tolist(), {"snap_limit_m": float(limit), "max_snap_m": max_snap_m}


def read_demand_csv(city: City, path: Path | str, *, date: str | None = None) -> DemandSet:
    """Read a user's demand file (format in the module docstring) into a :class:`DemandSet`.

    Parameters
    ----------
    city : City
        The network ids refer to / positions snap to, the timezone and horizon.
    path : path
        CSV file, plain or ``.gz``.
    date : str, optional
        Local date ``YYYY-MM-DD`` of the set; default: the local date of the first data row's time.

    Returns
    -------
    DemandSet
        ``generator="csv"``, ``seed=None``, ``params`` with the file name, the format (``"node"`` or
        ``"lonlat"``), the ignored columns and, for lon/lat files, the snap limit and the largest snap
        distance.

    Raises
    ------
    DemandFileError
        Naming the file and row of the first problem.
    """
    path = Path(path)
    name = path.name
    header, rows = read_csv_rows(path, ("request_id", "time"))
    columns = _columns(name, header)
    set_date = _set_date(name, rows, date, ZoneInfo(city.horizon.timezone))
    times, ends = _read_rows(name, rows, columns, city, set_date)
    params: dict[str, Any] = {
        "file": name,
        "format": "node" if columns is NODE_COLUMNS else "lonlat",
        "ignored_columns": [c for c in header if c not in columns],
    }
    if columns is NODE_COLUMNS:
        origins = [int(e[0]) for e in ends]
        dests = [int(e[1]) for e in ends]
    else:
        origins, dests, snap = _snapped_ends(name, rows, ends, city)
        params.update(snap)
    requests = sorted(
        (
            Request(rec["request_id"], float(t), o, d)
            for (_, rec), t, o, d in zip(rows, times, origins, dests, strict=True)
        ),
        key=lambda r: (r.time_s, r.id),
    )
    return DemandSet(city.name, set_date.isoformat(), tuple(requests), "csv", params=params)


def write_demand_csv(demand: DemandSet, city: City, path: Path | str) -> Path:
    """Write a set in the node-id format (``request_id,time,origin_node,destination_node``).

    Times are RFC 3339 at the city's UTC offset; a ``.gz`` name writes gzip. Returns the path.

    Raises
    ------
    ValueError
        If the set is for another city, or an id would not read back the same (empty, or surrounded by
        whitespace).
    """
    if demand.city != city.name:
        raise ValueError(f"the set is for city {demand.city!r}, not {city.name!r}")
    path = Path(path)
    tz = ZoneInfo(city.horizon.timezone)
    ids = city.network.node_ids
    buf = io.StringIO(newline="")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(NODE_COLUMNS)
    for r in demand.requests:
        if not r.id or r.id != r.id.strip():
            raise ValueError(f"request id {r.id!r} would not survive a CSV round trip")
        if r.time_s != int(r.time_s):
            raise ValueError(f"request {r.id!r}: time {r.time_s} is not whole seconds")
        when = dt.datetime.fromtimestamp(int(r.time_s), tz).isoformat()
        writer.writerow([r.id, when, int(ids[r.origin]), int(ids[r.destination])])
    data = buf.getvalue().encode("utf-8")
    if path.suffix == ".gz":
        path.write_bytes(gzip.compress(data, mtime=0))
    else:
        path.write_bytes(data)
    return path
