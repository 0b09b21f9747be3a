"""OpenAPI declarations of the error responses each route can give."""

from __future__ import annotations

from typing import Any

from app.schemas.common import ErrorOut

__all__ = ["errors", "READ_ERRORS", "WRITE_ERRORS"]

_DESCRIPTIONS = {
    400: "The body is not valid JSON (`bad_json`).",
    401: "Missing or unknown bearer token (`unauthorized`).",
    403: "The token lacks the required scope (`forbidden`).",
    404: "Unknown city (`unknown_city`) or epoch (`unknown_epoch`), route, or nothing yet (`no_data`).",
    409: "Conflict: `epoch_conflict`, `stale_epoch` or `task_conflict`.",
    413: "The body exceeds the configured size (`payload_too_large`).",
    415: "The body is not sent as `application/json` (`unsupported_media_type`).",
    422: "The request failed validation (`validation_error`); `fields` names the offending values.",
    500: "Unexpected failure (`internal`), logged.",
    503: "The store cannot be reached (`store_unavailable`), or too many concurrent commits or epochs being "
    "solved (`busy`); for POST .../fleet/solve, no fleet worker has been seen recently (`no_worker`).",
}


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """Responses entries for ``codes``, all with the ``ErrorOut`` shape."""
    return {code: {"model": ErrorOut, "description": _DESCRIPTIONS[code]} for code in codes}


READ_ERRORS = errors(401, 403, 404, 422, 500, 503)
WRITE_ERRORS = errors(400, 401, 403, 404, 409, 413, 415, 422, 500, 503)
