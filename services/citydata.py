"""Building a city from OSM XML, CSV or node-link JSON, and the on-disk bundle format.

Parsers return an :class:`ImportResult`: the largest strongly connected component of what was read, with
counts of what was dropped and why. Problems in the input raise :class:`CityDataError` naming the file,
the row (or line, or element) and the problem.

Bundle format (one directory per city)
--------------------------------------
``network.npz`` (``np.savez_compressed``)
    ``node_ids`` int64 (n,), ``lon``/``lat`` float64 (n,), ``edge_u``/``edge_v`` int32 (m,) node *indices*
    (or ``edge_u_id``/``edge_v_id`` int64 external ids instead), ``edge_length_m`` float64 (m,), optional
    ``edge_speed_kmh`` float64 (m,) (otherwise every edge runs at ``params.speed_kmh``).
``city.json``
    ``{"name", "timezone", "horizon": {"start": "08:00", "interval_s", "n_intervals", "epoch_s"},
    "params": {overrides of DispatchParams}, "cell_m": 1000, "source": attribution line,
    "built_with": {"script", "input", "sha256"}, "files": {role: file name in the bundle}}``.

The city built from a bundle weighs every cell the network touches equally (``s_g = 1/|touched|``, 0
elsewhere) and every interval of the horizon equally (``mu_t = 1/n_intervals``), docs/METHOD.md section 3.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as dt
import hashlib
import json
import math
import re
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import numpy as np
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from services.city import City, DispatchParams, Horizon
from services.network.network import Network, build_network, largest_strongly_connected
from services.sensing.grid import build_edge_cells, build_grid, touched_cells

__all__ = [
    "CityDataError",
    "ImportResult",
    "CityMeta",
    "DRIVABLE_HIGHWAYS",
    "EARTH_RADIUS_M",
    "MIN_OSM_LENGTH_M",
    "haversine_m",
    "validate_city_name",
    "read_osm",
    "read_csv_network",
    "read_node_link",
    "save_bundle",
    "read_meta",
    "load_network",
    "load_city",
    "city_from_network",
    "sha256_of",
]

EARTH_RADIUS_M = 6_371_009.0
"""Mean Earth radius used for haversine lengths (the value OSMnx uses)."""

DRIVABLE_HIGHWAYS: frozenset[str] = frozenset(
    {
        "motorway",
        "trunk",
        "primary",
        "secondary",
        "tertiary",
        "motorway_link",
        "trunk_link",
        "primary_link",
        "secondary_link",
        "tertiary_link",
        "unclassified",
        "residential",
        "living_street",
        "road",
    }
)
"""OSM ``highway`` values kept as drivable roads."""

MIN_OSM_LENGTH_M = 0.01
"""Length given to OSM edges between distinct nodes at the same position."""

_CITY_NAME = re.compile(r"[a-z0-9_-]{1,40}")
_INT = re.compile(r"\s*[+-]?\d+\s*")
_INT64_MAX = 2**63 - 1


class CityDataError(ValueError):
    """Input city data is malformed.

    Parameters
    ----------
    file : str
        The file's name (or path).
    row : int or None
        1-based data row (CSV, header excluded), line, or element number; None for whole-file problems.
    problem : str
        What is wrong.
    unit : str
        What ``row`` counts: ``"row"``, ``"line"``, ``"node"``, ``"link"``...
    """

    def __init__(self, file: str, row: int | None, problem: str, unit: str = "row") -> None:
        self.file = file
        self.row = row
        self.problem = problem
        self.unit = unit
        where = f"{file}, {unit} {row}" if row is not None else file
        super().__init__(f"{where}: {problem}")


@dataclass(frozen=True, slots=True)
class ImportResult:
    """A network read from a file, reduced to its largest strongly connected component.

    Attributes
    ----------
    network : Network
        The largest strongly connected component.
    nodes_read, edges_read : int
        Nodes and directed edges read (edges after dropping self-loops and parallel duplicates).
    nodes_dropped, edges_dropped : int
        Removed because they lie outside the largest strongly connected component.
    notes : tuple of str
        Other things the reader skipped or changed (self-loops, parallel edges, dangling references).
    """

    network: Network
    nodes_read: int
    edges_read: int
    nodes_dropped: int
    edges_dropped: int
    notes: tuple[str, ...] = ()

    def summary(self) -> str:
        """One line: size of the result and what was dropped."""
        km = float(self.network.edge_length_m.sum()) / 1000.0
        text = (
            f"{self.network.n_nodes} nodes, {self.network.n_edges} edges, {km:.1f} km; "
            f"dropped {self.nodes_dropped} nodes / {self.edges_dropped} edges outside the largest "
            f"strongly connected component"
        )
        return text + "".join(f"; {n}" for n in self.notes)


def validate_city_name(name: str) -> str:
    """Return ``name`` if it is a valid city name (lowercase ``[a-z0-9_-]``, 1-40 characters).

    Raises
    ------
    ValueError
        Otherwise.
    """
    if not isinstance(name, str) or not _CITY_NAME.fullmatch(name):
        raise ValueError(f"invalid city name {name!r}: use 1-40 characters from a-z, 0-9, '_' and '-'")
    return name


def haversine_m(
    lon1: NDArray[np.float64] | float,
    lat1: NDArray[np.float64] | float,
    lon2: NDArray[np.float64] | float,
    lat2: NDArray[np.float64] | float,
) -> NDArray[np.float64]:
    """Great-circle distance in metres on a sphere of radius :data:`EARTH_RADIUS_M`."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dphi = p2 - p1
    dlam = np.radians(np.asarray(lon2) - np.asarray(lon1))
    a = np.sin(dphi / 2.0) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dlam / 2.0) ** 2
    return np.asarray(2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0))), dtype=np.float64)


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _finish(
    node_ids: NDArray[np.int64],
    lon: NDArray[np.float64],
    lat: NDArray[np.float64],
    u_ids: NDArray[np.int64],
    v_ids: NDArray[np.int64],
    length_m: NDArray[np.float64],
    speed_kmh: NDArray[np.float64] | None,
    default_speed_kmh: float,
    notes: list[str],
) -> ImportResult:
    loops = int((u_ids == v_ids).sum())
    if loops:
        notes.append(f"{loops} self-loops dropped")
    full = build_network(node_ids, lon, lat, u_ids, v_ids, length_m, speed_kmh, default_speed_kmh)
    parallel = int(u_ids.size) - loops - full.n_edges
    if parallel:
        notes.append(f"{parallel} parallel edges dropped (kept the shortest)")
    scc = largest_strongly_connected(full)
    return ImportResult(
        network=scc,
        nodes_read=full.n_nodes,
        edges_read=full.n_edges,
        nodes_dropped=full.n_nodes - scc.n_nodes,
        edges_dropped=full.n_edges - scc.n_edges,
        notes=tuple(notes),
    )


# --------------------------------------------------------------------------------------------- OSM XML


def _direction(tags: Mapping[str, str]) -> tuple[bool, bool]:
    """(forward, backward) travel allowed on an OSM way."""
    oneway = tags.get("oneway", "").strip().lower()
    if oneway in ("yes", "true", "1"):
        return True, False
    if oneway == "-1":
        return False, True
    if oneway == "no":
        return True, True
    if tags.get("junction") == "roundabout" or tags.get("highway") == "motorway":
        return True, False
    return True, True


def _drivable(tags: Mapping[str, str]) -> bool:
    return (
        tags.get("highway") in DRIVABLE_HIGHWAYS
        and tags.get("access") not in ("private", "no")
        and tags.get("area") != "yes"
    )


def read_osm(path: Path | str, default_speed_kmh: float = 35.0) -> ImportResult:
    """Read the drivable road network of an OSM XML file.

    Keeps ways whose ``highway`` is in :data:`DRIVABLE_HIGHWAYS`, skipping ``access=private|no`` and
    ``area=yes``. Direction: ``oneway=yes|true|1`` forward only, ``oneway=-1`` reverse only,
    ``junction=roundabout`` and ``highway=motorway`` one way unless ``oneway=no``; otherwise both. No
    simplification: one edge per consecutive pair of way nodes, its length the haversine distance. Every
    edge runs at ``default_speed_kmh``. The result is the largest strongly connected component.

    Raises
    ------
    CityDataError
        On malformed XML (naming the line), a node without a valid lat/lon, or no drivable road at all.
    """
    path = Path(path)
    fname = path.name
    coords: dict[int, tuple[float, float]] = {}
    ways: list[tuple[list[int], bool, bool]] = []
    n_ways = 0
    try:
        context = ET.iterparse(str(path), events=("start", "end"))
        _, root = next(context)
        for event, elem in context:
            if event != "end":
                continue
            if elem.tag == "node":
                nid = elem.get("id")
                try:
                    lat = float(elem.get("lat", "nan"))
                    lon = float(elem.get("lon", "nan"))
                    if nid is None or not _INT.fullmatch(nid):
                        raise ValueError
                except ValueError:
                    raise CityDataError(fname, None, f"node {nid!r} lacks a valid id, lat or lon") from None
                if not (math.isfinite(lat) and math.isfinite(lon) and abs(lon) <= 180 and abs(lat) <= 90):
                    raise CityDataError(fname, None, f"node {nid} has lat/lon outside WGS84: {lat}, {lon}")
                coords[int(nid)] = (lon, lat)
                root.clear()
            elif elem.tag == "way":
                n_ways += 1
                tags = {t.get("k", ""): t.get("v", "") for t in elem.iter("tag")}
                if _drivable(tags):
                    refs = []
                    for nd in elem.iter("nd"):
                        ref = nd.get("ref", "")
                        if not _INT.fullmatch(ref):
                            raise CityDataError(
                                fname, None, f"way {elem.get('id')} has a bad node ref {ref!r}"
                            )
                        refs.append(int(ref))
                    fwd, bwd = _direction(tags)
                    ways.append((refs, fwd, bwd))
                root.clear()
            elif elem.tag == "relation":
                root.clear()
    except ET.ParseError as exc:
        line = exc.position[0] if exc.position else None
        raise CityDataError(fname, line, f"malformed XML ({exc})", unit="line") from None
    except StopIteration:
        raise CityDataError(fname, None, "empty file") from None
    except OSError as exc:
        raise CityDataError(fname, None, f"cannot read: {exc.strerror or exc}") from None

    us: list[int] = []
    vs: list[int] = []
    dangling = 0
    for refs, fwd, bwd in ways:
        for a, b in zip(refs[:-1], refs[1:], strict=True):
            if a not in coords or b not in coords:
                dangling += 1
                continue
            if fwd:
                us.append(a)
                vs.append(b)
            if bwd:
                us.append(b)
                vs.append(a)
    if not us:
        raise CityDataError(fname, None, f"no drivable road among {n_ways} ways")
    notes = [f"{len(ways)} drivable ways of {n_ways}"]
    if dangling:
        notes.append(f"{dangling} way segments skipped (node missing from the extract)")
    u_ids = np.array(us, dtype=np.int64)
    v_ids = np.array(vs, dtype=np.int64)
    node_ids = np.unique(np.concatenate([u_ids, v_ids]))
    lonlat = np.array([coords[int(i)] for i in node_ids], dtype=np.float64)
    pos = np.searchsorted(node_ids, np.concatenate([u_ids, v_ids]))
    m = u_ids.size
    length = haversine_m(lonlat[pos[:m], 0], lonlat[pos[:m], 1], lonlat[pos[m:], 0], lonlat[pos[m:], 1])
    # distinct OSM nodes at one position: a zero-weight edge invites trouble in sparse graph code
    tiny = (length < MIN_OSM_LENGTH_M) & (u_ids != v_ids)
    if tiny.any():
        notes.append(f"{int(tiny.sum())} edges between coincident nodes set to {MIN_OSM_LENGTH_M} m")
        length[tiny] = MIN_OSM_LENGTH_M
    return _finish(node_ids, lonlat[:, 0], lonlat[:, 1], u_ids, v_ids, length, None, default_speed_kmh, notes)


# ------------------------------------------------------------------------------------------------- CSV


def _read_csv(
    path: Path, required: tuple[str, ...], optional: tuple[str, ...]
) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """Header and (row number, fields) of a CSV file; rows are numbered from 1 after the header."""
    fname = path.name
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header: list[str] | None = None
            rows: list[tuple[int, list[str]]] = []
            for fields in reader:
                if header is None:
                    if not fields or all(not c.strip() for c in fields):
                        continue
                    header = [c.strip() for c in fields]
                    header_line = reader.line_num
                    continue
                if not fields or all(not c.strip() for c in fields):
                    continue
                rows.append((reader.line_num - header_line, fields))
    except OSError as exc:
        raise CityDataError(fname, None, f"cannot read: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise CityDataError(fname, None, f"not a UTF-8 CSV file ({exc})") from None
    if header is None:
        raise CityDataError(fname, None, "empty file (expected a header line)")
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise CityDataError(fname, 1, f"duplicate header column(s) {', '.join(dup)}", unit="line")
    missing = [c for c in required if c not in header]
    if missing:
        raise CityDataError(fname, 1, f"missing header column(s) {', '.join(missing)}", unit="line")
    extra = [c for c in header if c not in required and c not in optional]
    if extra:
        allowed = ", ".join(required + optional)
        raise CityDataError(
            fname, 1, f"unexpected header column(s) {', '.join(extra)} (allowed: {allowed})", unit="line"
        )
    if not rows:
        raise CityDataError(fname, None, "no data rows after the header")
    for row, fields in rows:
        if len(fields) != len(header):
            raise CityDataError(fname, row, f"expected {len(header)} fields, found {len(fields)}")
    return header, rows


def _int_field(fname: str, row: int, col: str, text: str) -> int:
    if not _INT.fullmatch(text):
        raise CityDataError(fname, row, f"{col} must be an integer, got {text!r}")
    value = int(text)
    if abs(value) > _INT64_MAX:
        raise CityDataError(fname, row, f"{col} {text} does not fit in 64 bits")
    return value


def _float_field(fname: str, row: int, col: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise CityDataError(fname, row, f"{col} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise CityDataError(fname, row, f"{col} must be finite, got {text!r}")
    return value


def read_csv_network(
    nodes_path: Path | str, edges_path: Path | str, default_speed_kmh: float = 35.0
) -> ImportResult:
    """Read a network from ``nodes.csv`` and ``edges.csv``.

    ``nodes.csv`` has the header ``id,lon,lat`` (integer ids, WGS84 degrees); ``edges.csv`` has
    ``u,v,length_m`` and optionally ``speed_kmh`` (blank: ``default_speed_kmh``), one row per direction.
    Columns may come in any order. The result is the largest strongly connected component.

    Raises
    ------
    CityDataError
        Naming the file and row for: missing, duplicate or unexpected header columns, a wrong number of
        fields, non-numeric or non-finite values, lon outside [-180, 180] or lat outside [-90, 90],
        duplicate node ids, edges naming unknown nodes, ``length_m <= 0``, ``speed_kmh <= 0`` and empty
        files.
    """
    npath, epath = Path(nodes_path), Path(edges_path)
    nname, ename = npath.name, epath.name
    header, rows = _read_csv(npath, ("id", "lon", "lat"), ())
    ci, cx, cy = header.index("id"), header.index("lon"), header.index("lat")
    ids: list[int] = []
    lons: list[float] = []
    lats: list[float] = []
    seen: dict[int, int] = {}
    for row, f in rows:
        nid = _int_field(nname, row, "id", f[ci])
        lon = _float_field(nname, row, "lon", f[cx])
        lat = _float_field(nname, row, "lat", f[cy])
        if not -180.0 <= lon <= 180.0:
            raise CityDataError(nname, row, f"lon {lon} outside [-180, 180]")
        if not -90.0 <= lat <= 90.0:
            raise CityDataError(nname, row, f"lat {lat} outside [-90, 90]")
        if nid in seen:
            raise CityDataError(nname, row, f"duplicate node id {nid} (first in row {seen[nid]})")
        seen[nid] = row
        ids.append(nid)
        lons.append(lon)
        lats.append(lat)

    header, rows = _read_csv(epath, ("u", "v", "length_m"), ("speed_kmh",))
    cu, cv, cl = header.index("u"), header.index("v"), header.index("length_m")
    cs = header.index("speed_kmh") if "speed_kmh" in header else None
    us: list[int] = []
    vs: list[int] = []
    lengths: list[float] = []
    speeds: list[float] = []
    for row, f in rows:
        u = _int_field(ename, row, "u", f[cu])
        v = _int_field(ename, row, "v", f[cv])
        for col, nid in (("u", u), ("v", v)):
            if nid not in seen:
                raise CityDataError(ename, row, f"{col} names unknown node id {nid}")
        length = _float_field(ename, row, "length_m", f[cl])
        if length <= 0:
            raise CityDataError(ename, row, f"length_m must be positive, got {f[cl].strip()}")
        speed = math.nan
        if cs is not None and f[cs].strip():
            speed = _float_field(ename, row, "speed_kmh", f[cs])
            if speed <= 0:
                raise CityDataError(ename, row, f"speed_kmh must be positive, got {f[cs].strip()}")
        us.append(u)
        vs.append(v)
        lengths.append(length)
        speeds.append(speed)
    return _finish(
        np.array(ids, dtype=np.int64),
        np.array(lons, dtype=np.float64),
        np.array(lats, dtype=np.float64),
        np.array(us, dtype=np.int64),
        np.array(vs, dtype=np.int64),
        np.array(lengths, dtype=np.float64),
        np.array(speeds, dtype=np.float64) if cs is not None else None,
        default_speed_kmh,
        [],
    )


# ------------------------------------------------------------------------------------ node-link JSON


def read_node_link(path: Path | str, default_speed_kmh: float = 35.0) -> ImportResult:
    """Read a networkx node-link JSON network (nodes ``id, x=lon, y=lat``; links ``source, target, length``).

    Speeds or travel times in the file are ignored: every edge runs at ``default_speed_kmh``
    (docs/METHOD.md section 10 uses a constant 35 km/h). Parallel links keep the shortest.

    Raises
    ------
    CityDataError
        On malformed JSON, a node or link missing a field or holding a bad value (naming its position,
        1-based), or links naming unknown nodes.
    """
    path = Path(path)
    fname = path.name
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CityDataError(fname, None, f"cannot read: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        line = getattr(exc, "lineno", None)
        raise CityDataError(fname, line, f"malformed JSON ({exc})", unit="line") from None
    if not isinstance(data, dict) or not isinstance(data.get("nodes"), list):
        raise CityDataError(fname, None, "expected an object with 'nodes' and 'links' (or 'edges') lists")
    links = data.get("links", data.get("edges"))
    if not isinstance(links, list):
        raise CityDataError(fname, None, "expected a 'links' (or 'edges') list")
    ids: list[int] = []
    lons: list[float] = []
    lats: list[float] = []
    for i, node in enumerate(data["nodes"], start=1):
        try:
            nid, lon, lat = node["id"], float(node["x"]), float(node["y"])
            if isinstance(nid, bool) or not isinstance(nid, int):
                raise ValueError
        except (KeyError, TypeError, ValueError):
            raise CityDataError(
                fname, i, "needs an integer 'id' and numeric 'x' (lon), 'y' (lat)", "node"
            ) from None
        if not (math.isfinite(lon) and math.isfinite(lat) and abs(lon) <= 180 and abs(lat) <= 90):
            raise CityDataError(fname, i, f"x/y outside WGS84: {lon}, {lat}", "node")
        ids.append(nid)
        lons.append(lon)
        lats.append(lat)
    known = set(ids)
    if len(known) != len(ids):
        raise CityDataError(fname, None, "duplicate node ids")
    us: list[int] = []
    vs: list[int] = []
    lengths: list[float] = []
    for i, link in enumerate(links, start=1):
        try:
            u, v, length = link["source"], link["target"], float(link["length"])
        except (KeyError, TypeError, ValueError):
            raise CityDataError(fname, i, "needs 'source', 'target' and a numeric 'length'", "link") from None
        if u not in known or v not in known:
            raise CityDataError(fname, i, f"names an unknown node ({u} -> {v})", "link")
        if not (math.isfinite(length) and length > 0):
            raise CityDataError(fname, i, f"length must be positive, got {length}", "link")
        us.append(u)
        vs.append(v)
        lengths.append(length)
    if not us:
        raise CityDataError(fname, None, "no links")
    return _finish(
        np.array(ids, dtype=np.int64),
        np.array(lons, dtype=np.float64),
        np.array(lats, dtype=np.float64),
        np.array(us, dtype=np.int64),
        np.array(vs, dtype=np.int64),
        np.array(lengths, dtype=np.float64),
        None,
        default_speed_kmh,
        [],
    )


# ---------------------------------------------------------------------------------------------- bundle


@dataclass(frozen=True, slots=True)
class CityMeta:
    """The contents of a bundle's ``city.json``.

    ``params`` holds overrides of :class:`services.city.DispatchParams` fields (JSON values; lists for
    tuples). ``files`` maps a role (``"pois"``, ``"requests"``...) to a file name inside the bundle.
    """

    name: str
    timezone: str = "UTC"
    start: str = "08:00"
    interval_s: int = 3600
    n_intervals: int = 4
    epoch_s: int = 200
    params: dict[str, Any] = field(default_factory=dict)
    cell_m: float = 1000.0
    source: str = ""
    built_with: dict[str, Any] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)

    def horizon(self) -> Horizon:
        """The :class:`Horizon` described (raises ``ValueError`` when invalid)."""
        try:
            ZoneInfo(self.timezone)
        except (ZoneInfoNotFoundError, ValueError, TypeError):
            raise ValueError(f"unknown timezone {self.timezone!r}") from None
        m = re.fullmatch(r"(\d{1,2}):(\d{2})", str(self.start))
        if not m or int(m.group(1)) > 23 or int(m.group(2)) > 59:
            raise ValueError(f"start must be HH:MM, got {self.start!r}")
        return Horizon(
            timezone=self.timezone,
            start=dt.time(int(m.group(1)), int(m.group(2))),
            interval_s=self.interval_s,
            n_intervals=self.n_intervals,
            epoch_s=self.epoch_s,
        )

    def dispatch_params(self) -> DispatchParams:
        """:class:`DispatchParams` with the overrides applied (raises ``ValueError`` when invalid)."""
        known = {f.name: f for f in dataclasses.fields(DispatchParams)}
        kwargs: dict[str, Any] = {}
        for key, value in self.params.items():
            if key not in known:
                raise ValueError(f"unknown dispatch parameter {key!r}")
            kwargs[key] = tuple(value) if isinstance(value, list) else value
        try:
            return DispatchParams(**kwargs)
        except TypeError as exc:
            raise ValueError(str(exc)) from None

    def validate(self) -> None:
        """Raise ``ValueError`` if any field is invalid."""
        validate_city_name(self.name)
        self.horizon()
        self.dispatch_params()
        if not (isinstance(self.cell_m, int | float) and math.isfinite(self.cell_m) and self.cell_m > 0):
            raise ValueError("cell_m must be positive")

    def to_json(self) -> dict[str, Any]:
        """The ``city.json`` object."""
        return {
            "name": self.name,
            "timezone": self.timezone,
            "horizon": {
                "start": self.start,
                "interval_s": self.interval_s,
                "n_intervals": self.n_intervals,
                "epoch_s": self.epoch_s,
            },
            "params": dict(self.params),
            "cell_m": self.cell_m,
            "source": self.source,
            "built_with": dict(self.built_with),
            "files": dict(self.files),
        }

    @classmethod
    def from_json(cls, obj: Any) -> CityMeta:
        """Parse a ``city.json`` object (raises ``ValueError`` naming the problem)."""
        if not isinstance(obj, dict):
            raise ValueError("expected a JSON object")
        extra = set(obj) - {
            "name",
            "timezone",
            "horizon",
            "params",
            "cell_m",
            "source",
            "built_with",
            "files",
        }
        if extra:
            raise ValueError(f"unknown key(s) {', '.join(sorted(extra))}")
        hz = obj.get("horizon", {})
        if not isinstance(hz, dict) or set(hz) - {"start", "interval_s", "n_intervals", "epoch_s"}:
            raise ValueError("horizon must be an object with start, interval_s, n_intervals, epoch_s")
        for key in ("params", "built_with", "files"):
            if not isinstance(obj.get(key, {}), dict):
                raise ValueError(f"{key} must be an object")
        for key in ("interval_s", "n_intervals", "epoch_s"):
            if key in hz and (isinstance(hz[key], bool) or not isinstance(hz[key], int)):
                raise ValueError(f"horizon.{key} must be an integer")
        if "name" not in obj:
            raise ValueError("missing 'name'")
        meta = cls(
            name=obj["name"],
            timezone=obj.get("timezone", "UTC"),
            start=hz.get("start", "08:00"),
            interval_s=hz.get("interval_s", 3600),
            n_intervals=hz.get("n_intervals", 4),
            epoch_s=hz.get("epoch_s", 200),
            params=dict(obj.get("params", {})),
            cell_m=obj.get("cell_m", 1000.0),
            source=obj.get("source", ""),
            built_with=dict(obj.get("built_with", {})),
            files=dict(obj.get("files", {})),
        )
        meta.validate()
        return meta


def _write_npz(path: Path, arrays: Mapping[str, NDArray[Any]]) -> None:
    """What ``np.savez_compressed`` writes, with fixed timestamps so rebuilding gives identical bytes."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, arr in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arr), allow_pickle=False)


def save_bundle(directory: Path | str, network: Network, meta: CityMeta) -> Path:
    """Write ``network.npz`` and ``city.json`` into ``directory`` (created if needed).

    Returns
    -------
    Path
        The directory.
    """
    meta.validate()
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, NDArray[Any]] = {
        "node_ids": network.node_ids.astype(np.int64),
        "lon": network.lon.astype(np.float64),
        "lat": network.lat.astype(np.float64),
        "edge_u": network.edge_u.astype(np.int32),
        "edge_v": network.edge_v.astype(np.int32),
        "edge_length_m": network.edge_length_m.astype(np.float64),
    }
    # per-edge speeds are stored only where the network does not run at the city's one speed
    speed_kmh = meta.dispatch_params().speed_kmh
    expected_s = network.edge_length_m / (speed_kmh / 3.6)
    if not np.allclose(network.edge_time_s, expected_s, rtol=1e-9, atol=1e-9):
        with np.errstate(divide="ignore", invalid="ignore"):
            speed = network.edge_length_m / network.edge_time_s * 3.6
        arrays["edge_speed_kmh"] = np.where(np.isfinite(speed) & (speed > 0), speed, np.nan)
    _write_npz(d / "network.npz", arrays)
    (d / "city.json").write_text(json.dumps(meta.to_json(), indent=2, ensure_ascii=False) + "\n", "utf-8")
    return d


def read_meta(directory: Path | str) -> CityMeta:
    """Parse a bundle's ``city.json``.

    Raises
    ------
    CityDataError
        If it is missing or invalid.
    """
    path = Path(directory) / "city.json"
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CityDataError(str(path), None, f"cannot read: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise CityDataError(str(path), exc.lineno, f"malformed JSON ({exc.msg})", unit="line") from None
    try:
        return CityMeta.from_json(obj)
    except ValueError as exc:
        raise CityDataError(str(path), None, str(exc)) from None


def load_network(directory: Path | str, default_speed_kmh: float = 35.0) -> Network:
    """Build the :class:`Network` of a bundle's ``network.npz``.

    Raises
    ------
    CityDataError
        If the file is missing, lacks arrays, holds invalid values or is not strongly connected.
    """
    path = Path(directory) / "network.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise CityDataError(str(path), None, f"cannot read: {exc}") from None
    need = {"node_ids", "lon", "lat", "edge_length_m"}
    missing = need - set(arrays)
    if missing:
        raise CityDataError(str(path), None, f"missing array(s) {', '.join(sorted(missing))}")
    ids = arrays["node_ids"]
    try:
        if "edge_u" in arrays and "edge_v" in arrays:
            eu, ev = arrays["edge_u"].astype(np.int64), arrays["edge_v"].astype(np.int64)
            if eu.size and (min(eu.min(), ev.min()) < 0 or max(eu.max(), ev.max()) >= ids.size):
                raise ValueError("edge node index out of range")
            u_ids, v_ids = ids[eu], ids[ev]
        elif "edge_u_id" in arrays and "edge_v_id" in arrays:
            u_ids, v_ids = arrays["edge_u_id"], arrays["edge_v_id"]
        else:
            raise ValueError("missing edge_u/edge_v (or edge_u_id/edge_v_id)")
        net = build_network(
            ids,
            arrays["lon"],
            arrays["lat"],
            u_ids,
            v_ids,
            arrays["edge_length_m"],
            arrays.get("edge_speed_kmh"),
            default_speed_kmh,
        )
    except ValueError as exc:
        raise CityDataError(str(path), None, str(exc)) from None
    n_comp, _ = connected_components(
        net.csr(np.ones(net.n_edges)), directed=True, connection="strong", return_labels=True
    )
    if n_comp != 1:
        raise CityDataError(str(path), None, f"network is not strongly connected ({n_comp} components)")
    return net


def city_from_network(network: Network, meta: CityMeta) -> City:
    """Assemble a :class:`City`: grid, edge cells, uniform cell and interval weights, horizon, params."""
    try:
        horizon = meta.horizon()
        params = meta.dispatch_params()
    except ValueError as exc:
        raise CityDataError("city.json", None, str(exc)) from None
    grid = build_grid(network, float(meta.cell_m))
    edge_cells = build_edge_cells(grid, network)
    touched = touched_cells(grid, network, edge_cells)
    cell_weight = np.zeros(grid.n_cells, dtype=np.float64)
    cell_weight[touched] = 1.0 / touched.size
    interval_weight = np.full(horizon.n_intervals, 1.0 / horizon.n_intervals)
    return City(
        name=meta.name,
        network=network,
        grid=grid,
        edge_cells=edge_cells,
        horizon=horizon,
        params=params,
        cell_weight=cell_weight,
        interval_weight=interval_weight,
        source=meta.source,
    )


def load_city(directory: Path | str) -> City:
    """Load a city bundle (``network.npz`` + ``city.json``) into a :class:`City`.

    Raises
    ------
    CityDataError
        If either file is missing or invalid.
    """
    meta = read_meta(directory)
    network = load_network(directory, default_speed_kmh=meta.dispatch_params().speed_kmh)
    return city_from_network(network, meta)
