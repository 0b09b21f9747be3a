"""Reading a road network from OSM XML, CSV or node-link JSON (the bundles of ``services.citydata`` are
built from what these return).

Every reader returns an :class:`ImportResult`: the largest strongly connected component of what was read,
with counts of what was dropped and why. Problems in the input raise
:class:`services.citydata.CityDataError` naming the file, the row (or line, or element) and the problem.
"""

from __future__ import annotations

import csv
import json
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from services.citydata import CityDataError, haversine_m
from services.network.contraction import hilbert_key
from services.network.network import Network, build_network, largest_strongly_connected

__all__ = [
    "ImportResult",
    "DRIVABLE_HIGHWAYS",
    "MIN_OSM_LENGTH_M",
    "read_osm",
    "read_csv_network",
    "read_node_link",
]


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

_INT = re.compile(r"\s*[+-]?\d+\s*")
_INT64_MAX = 2**63 - 1


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
    # nodes numbered along a Hilbert curve, not in the file's order (an OpenStreetMap extract's is by
    # when they were mapped): the arrays a search reads for nearby nodes and edges then lie together
    if node_ids.shape == lon.shape == lat.shape and np.isfinite(lon).all() and np.isfinite(lat).all():
        along = np.argsort(hilbert_key(lon, lat), kind="stable")  # else build_network says what is wrong
        node_ids, lon, lat = node_ids[along], lon[along], lat[along]
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


_Way = tuple[list[int], bool, bool]
"""A drivable OSM way: its node ids in order, travel allowed forward and backward."""


def _osm_node(elem: ET.Element, fname: str) -> tuple[int, float, float]:
    """(id, lon, lat) of an OSM ``node`` element."""
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
    return int(nid), lon, lat


def _osm_way(elem: ET.Element, fname: str) -> _Way | None:
    """The drivable way of an OSM ``way`` element (None when it is not drivable)."""
    tags = {t.get("k", ""): t.get("v", "") for t in elem.iter("tag")}
    if not _drivable(tags):
        return None
    refs = []
    for nd in elem.iter("nd"):
        ref = nd.get("ref", "")
        if not _INT.fullmatch(ref):
            raise CityDataError(fname, None, f"way {elem.get('id')} has a bad node ref {ref!r}")
        refs.append(int(ref))
    fwd, bwd = _direction(tags)
    return refs, fwd, bwd


def _osm_elements(path: Path) -> tuple[dict[int, tuple[float, float]], list[_Way], int]:
    """The node positions (lon, lat) by id, the drivable ways and the number of ways of an OSM XML file,
    read element by element (each dropped once read)."""
    fname = path.name
    coords: dict[int, tuple[float, float]] = {}
    ways: list[_Way] = []
    n_ways = 0
    try:
        context = ET.iterparse(str(path), events=("start", "end"))
        _, root = next(context)
        for event, elem in context:
            if event != "end":
                continue
            if elem.tag == "node":
                nid, lon, lat = _osm_node(elem, fname)
                coords[nid] = (lon, lat)
                root.clear()
            elif elem.tag == "way":
                n_ways += 1
                way = _osm_way(elem, fname)
                if way is not None:
                    ways.append(way)
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
    return coords, ways, n_ways


def _osm_segments(coords: Mapping[int, object], ways: list[_Way]) -> tuple[list[int], list[int], int]:
    """The directed segments (from ids, to ids) of the ways, and the number skipped for a missing node."""
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
    return us, vs, dangling


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
    coords, ways, n_ways = _osm_elements(path)
    us, vs, dangling = _osm_segments(coords, ways)
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
