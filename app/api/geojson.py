"""Serving GeoJSON (RFC 7946): the ``application/geo+json`` media type, its OpenAPI declaration, compact
JSON text, and gzip for the large documents when the client accepts it."""

from __future__ import annotations

import gzip
import json
from typing import Any

from fastapi import Request, Response

from services.geojson import GeoJson

__all__ = ["GEOJSON", "geojson_responses", "dump", "Packed", "pack", "respond"]

GEOJSON = "application/geo+json"

_COLLECTION_SCHEMA = {
    "type": "object",
    "description": "An RFC 7946 FeatureCollection (WGS84 [lon, lat]).",
    "required": ["type", "features"],
    "properties": {
        "type": {"type": "string", "enum": ["FeatureCollection"]},
        "features": {"type": "array", "items": {"type": "object"}},
        "bbox": {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4},
    },
}


def geojson_responses(description: str) -> dict[int | str, dict[str, Any]]:
    """The 200 entry of a route answering a FeatureCollection (``description`` lists its properties)."""
    return {200: {"description": description, "content": {GEOJSON: {"schema": _COLLECTION_SCHEMA}}}}


def dump(doc: GeoJson) -> bytes:
    """Compact JSON text of a GeoJSON document (refusing NaN and infinity, which JSON has not)."""
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


class Packed:
    """A document's text and its gzip form, made once (for documents served again and again)."""

    __slots__ = ("plain", "gzipped")

    def __init__(self, plain: bytes) -> None:
        self.plain = plain
        self.gzipped = gzip.compress(plain, compresslevel=6, mtime=0)


def pack(doc: GeoJson) -> Packed:
    """``doc`` as text and gzipped text."""
    return Packed(dump(doc))


def _accepts_gzip(request: Request) -> bool:
    for part in request.headers.get("accept-encoding", "").split(","):
        name, _, params = part.strip().partition(";")
        if name.strip().lower() in ("gzip", "*"):
            q = params.strip().removeprefix("q=")
            try:
                return not params or float(q) > 0
            except ValueError:
                return False
    return False


def respond(request: Request, doc: bytes | Packed) -> Response:
    """The document as ``application/geo+json``; gzipped when it is packed and the client accepts gzip."""
    if isinstance(doc, bytes):
        return Response(content=doc, media_type=GEOJSON)
    if _accepts_gzip(request):
        headers = {"Content-Encoding": "gzip", "Vary": "Accept-Encoding"}
        return Response(content=doc.gzipped, media_type=GEOJSON, headers=headers)
    return Response(content=doc.plain, media_type=GEOJSON, headers={"Vary": "Accept-Encoding"})
