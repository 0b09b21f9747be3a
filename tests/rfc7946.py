"""An RFC 7946 checker for the GeoJSON the service writes (written from the RFC, independent of the code
under test): structure of every object, WGS84 positions in [lon, lat] order, LineStrings of two or more
positions, Polygon rings closed, at least four positions, exterior counterclockwise and holes clockwise
(section 3.1.6), rings simple where they are convex quadrilaterals, bbox enclosing the coordinates, and no
NaN or infinity anywhere (JSON has none)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

__all__ = ["problems", "signed_area", "positions"]

_GEOMETRIES = {"Point", "MultiPoint", "LineString", "MultiLineString", "Polygon", "MultiPolygon"}


def signed_area(ring: list[list[float]]) -> float:
    """Shoelace area of a ring in (lon, lat) degrees: positive when counterclockwise."""
    return 0.5 * sum(ring[i][0] * ring[i + 1][1] - ring[i + 1][0] * ring[i][1] for i in range(len(ring) - 1))


def _position(p: Any, where: str) -> list[str]:
    if not isinstance(p, list) or len(p) not in (2, 3):
        return [f"{where}: a position is an array of 2 (or 3) numbers, got {p!r}"]
    if not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in p):
        return [f"{where}: position {p!r} has a non-number"]
    lon, lat = p[0], p[1]
    if not (-180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):
        return [f"{where}: position {p!r} is not [lon, lat] in WGS84 degrees"]
    return []


def _convex_quad_is_simple(ring: list[list[float]]) -> bool:
    """A closed ring of 4 distinct corners is simple iff all its turns have the same sign (convex)."""
    turns = []
    for i in range(4):
        a, b, c = ring[i], ring[(i + 1) % 4], ring[(i + 2) % 4]
        turns.append((b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]))
    return all(t > 0 for t in turns) or all(t < 0 for t in turns)


def _geometry(g: Any, where: str) -> list[str]:
    if not isinstance(g, dict) or g.get("type") not in _GEOMETRIES | {"GeometryCollection"}:
        return [f"{where}: not a geometry object: {str(g)[:80]}"]
    kind = g["type"]
    if kind == "GeometryCollection":
        return [e for i, sub in enumerate(g.get("geometries", [])) for e in _geometry(sub, f"{where}[{i}]")]
    coords = g.get("coordinates")
    if not isinstance(coords, list):
        return [f"{where}: {kind} without a coordinates array"]
    out: list[str] = []
    if kind == "Point":
        return _position(coords, where)
    if kind in ("MultiPoint", "LineString"):
        out += [e for i, p in enumerate(coords) for e in _position(p, f"{where}[{i}]")]
        if kind == "LineString" and len(coords) < 2:
            out.append(f"{where}: a LineString has two or more positions")
        return out
    if kind in ("MultiLineString", "MultiPolygon"):
        part = kind.removeprefix("Multi")
        for i, sub in enumerate(coords):
            out += _geometry({"type": part, "coordinates": sub}, f"{where}[{i}]")
        return out
    if not coords:
        return [f"{where}: a Polygon has at least its exterior ring"]
    for r, ring in enumerate(coords):
        w = f"{where}.ring[{r}]"
        if not isinstance(ring, list):
            out.append(f"{w}: not an array")
            continue
        bad = [e for i, p in enumerate(ring) for e in _position(p, f"{w}[{i}]")]
        if bad:
            out += bad
            continue
        if len(ring) < 4:
            out.append(f"{w}: a linear ring has four or more positions")
            continue
        if ring[0] != ring[-1]:
            out.append(f"{w}: not closed (first {ring[0]} != last {ring[-1]})")
            continue
        area = signed_area(ring)
        if r == 0 and not area > 0:
            out.append(f"{w}: the exterior ring must be counterclockwise (signed area {area})")
        if r > 0 and not area < 0:
            out.append(f"{w}: a hole must be clockwise (signed area {area})")
        if len(ring) == 5 and not _convex_quad_is_simple(ring):
            out.append(f"{w}: the quadrilateral is not simple and convex")
    return out


def positions(doc: Any) -> Iterator[list[float]]:
    """Every position inside a GeoJSON object."""

    def walk(c: Any) -> Iterator[list[float]]:
        if isinstance(c, list) and c and isinstance(c[0], int | float):
            yield c
        elif isinstance(c, list):
            for x in c:
                yield from walk(x)

    if isinstance(doc, dict):
        if "coordinates" in doc:
            yield from walk(doc["coordinates"])
        for key in ("geometry", "geometries", "features"):
            sub = doc.get(key)
            for item in sub if isinstance(sub, list) else [sub] if sub else []:
                yield from positions(item)


def _bbox(doc: dict[str, Any], where: str) -> list[str]:
    if "bbox" not in doc:
        return []
    b = doc["bbox"]
    if not (isinstance(b, list) and len(b) == 4 and all(isinstance(v, int | float) for v in b)):
        return [f"{where}: bbox must be [west, south, east, north]"]
    out = []
    for p in positions(doc):
        if not (b[0] <= p[0] <= b[2] and b[1] <= p[1] <= b[3]):
            out.append(f"{where}: position {p} lies outside the bbox {b}")
            break
    return out


def problems(doc: Any) -> list[str]:
    """Every way ``doc`` (a parsed GeoJSON text) breaks RFC 7946; empty when it is valid."""
    try:
        json.dumps(doc, allow_nan=False)
    except ValueError as exc:
        return [f"not JSON: {exc}"]
    if not isinstance(doc, dict):
        return ["a GeoJSON text is an object"]
    kind = doc.get("type")
    if kind == "FeatureCollection":
        feats = doc.get("features")
        if not isinstance(feats, list):
            return ["a FeatureCollection has a features array"]
        out = _bbox(doc, "collection")
        for i, f in enumerate(feats):
            out += _feature(f, f"features[{i}]")
        return out
    if kind == "Feature":
        return _feature(doc, "feature")
    return _geometry(doc, "geometry")


def _feature(f: Any, where: str) -> list[str]:
    if not isinstance(f, dict) or f.get("type") != "Feature":
        return [f"{where}: not a Feature"]
    out = []
    if "geometry" not in f:
        out.append(f"{where}: a Feature has a geometry member (object or null)")
    elif f["geometry"] is not None:
        out += _geometry(f["geometry"], f"{where}.geometry")
    if "properties" not in f or not (f["properties"] is None or isinstance(f["properties"], dict)):
        out.append(f"{where}: a Feature has a properties member (object or null)")
    if "id" in f and not (isinstance(f["id"], str | int | float) and not isinstance(f["id"], bool)):
        out.append(f"{where}: id must be a string or a number")
    return out + _bbox(f, where)
