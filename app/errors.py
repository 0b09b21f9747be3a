"""The service's error hierarchy: each error carries its HTTP status, kind and offending fields."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

__all__ = [
    "FieldIssue",
    "ServiceError",
    "BadRequest",
    "InvalidInput",
    "Unauthorized",
    "Forbidden",
    "NotFound",
    "UnknownCity",
    "NoData",
    "UnknownEpoch",
    "MethodNotAllowed",
    "Conflict",
    "EpochConflict",
    "StaleEpoch",
    "TaskConflict",
    "RequestTimeout",
    "PayloadTooLarge",
    "UnsupportedMediaType",
    "Unavailable",
    "StoreUnavailable",
    "Busy",
    "NoWorker",
    "InternalError",
    "format_loc",
]


@dataclass(frozen=True, slots=True)
class FieldIssue:
    """One offending field: a dotted location such as ``riders[2].origin.lon`` and a message."""

    loc: str
    msg: str


def format_loc(parts: Iterable[Any]) -> str:
    """Render a pydantic-style location tuple as ``riders[2].origin.lon`` (``[3].id`` for a list body)."""
    out = ""
    for part in parts:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


class ServiceError(Exception):
    """Base of every error the API renders as ``{"error", "detail", "fields"}``."""

    status: ClassVar[int] = 500
    kind: ClassVar[str] = "internal"
    headers: ClassVar[dict[str, str]] = {}

    def __init__(self, detail: str, fields: Sequence[FieldIssue] = ()) -> None:
        super().__init__(detail)
        self.detail = detail
        self.fields = list(fields)

    def response_headers(self) -> dict[str, str]:
        """The headers of this error's response."""
        return dict(self.headers)

    def body(self) -> dict[str, Any]:
        """The JSON body of this error."""
        return {
            "error": self.kind,
            "detail": self.detail,
            "fields": [{"loc": f.loc, "msg": f.msg} for f in self.fields],
        }


class BadRequest(ServiceError):
    """The body is not JSON at all."""

    status = 400
    kind = "bad_json"


class InvalidInput(ServiceError):
    """The request parsed but failed validation (fields name the offending values)."""

    status = 422
    kind = "validation_error"

    @classmethod
    def at(cls, loc: str, msg: str) -> InvalidInput:
        """One-field validation error."""
        return cls(f"{loc}: {msg}", [FieldIssue(loc, msg)])


class Unauthorized(ServiceError):
    """No bearer token, or an unknown one."""

    status = 401
    kind = "unauthorized"
    headers = {"WWW-Authenticate": "Bearer"}


class Forbidden(ServiceError):
    """The token lacks the scope the operation needs."""

    status = 403
    kind = "forbidden"


class NotFound(ServiceError):
    """No such route or resource."""

    status = 404
    kind = "not_found"


class UnknownCity(NotFound, KeyError):
    """No city of that name is served (a 404 ``unknown_city``, and a ``KeyError`` for a lookup by name)."""

    kind = "unknown_city"

    def __str__(self) -> str:
        return self.detail


class NoData(NotFound):
    """Nothing to report yet (e.g. coverage before any epoch)."""

    kind = "no_data"


class UnknownEpoch(NotFound):
    """No committed epoch of the city has that id (never posted, or expired after the retention)."""

    kind = "unknown_epoch"


class MethodNotAllowed(ServiceError):
    """The route exists with other methods (named in the ``Allow`` header)."""

    status = 405
    kind = "method_not_allowed"

    def __init__(self, detail: str, fields: Sequence[FieldIssue] = (), *, allow: str = "") -> None:
        super().__init__(detail, fields)
        self.allow = allow

    def response_headers(self) -> dict[str, str]:
        """``Allow`` with the route's methods (RFC 9110: a 405 must carry it)."""
        return {"Allow": self.allow} if self.allow else {}


class Conflict(ServiceError):
    """The request conflicts with the stored state."""

    status = 409
    kind = "conflict"


class EpochConflict(Conflict):
    """An epoch with this id was committed with a different body."""

    kind = "epoch_conflict"


class StaleEpoch(Conflict):
    """The epoch's time is older than the last committed epoch."""

    kind = "stale_epoch"


class TaskConflict(Conflict):
    """Tasks with these ids exist with different content."""

    kind = "task_conflict"


class InsufficientHistory(Conflict):
    """A fleet solve asked for before the city has the M days of history it is sized on (the body says
    how many it has, how many it needs, and from which day a first solve is possible)."""

    kind = "insufficient_history"

    def __init__(self, detail: str, *, days: int, needed: int, first_solve_on: str) -> None:
        super().__init__(detail)
        self.history = {"days": days, "needed": needed, "first_solve_on": first_solve_on}

    def body(self) -> dict[str, Any]:
        """The error's body with the history it counted."""
        return {**super().body(), "history": dict(self.history)}


class RequestTimeout(ServiceError):
    """The client did not send the whole request in time; the connection is closed."""

    status = 408
    kind = "request_timeout"
    headers = {"Connection": "close"}


class PayloadTooLarge(ServiceError):
    """The body exceeds ``settings.server.max_body_bytes`` (``SD_MAX_BODY_BYTES``)."""

    status = 413
    kind = "payload_too_large"


class UnsupportedMediaType(ServiceError):
    """The body is not ``application/json``."""

    status = 415
    kind = "unsupported_media_type"


class Unavailable(ServiceError):
    """The service cannot answer right now."""

    status = 503
    kind = "unavailable"


class StoreUnavailable(Unavailable, RuntimeError):
    """The backing store cannot be reached: raised by the store adapters (``app.ports``), naming where and
    why for the log; the API answers 503 ``store_unavailable`` without either."""

    kind = "store_unavailable"


class Busy(Unavailable):
    """Too many concurrent commits on one city, or every solve slot taken; retry."""

    kind = "busy"


class NoWorker(Unavailable):
    """No fleet worker serving the city has been seen recently: a queued solve would wait for nobody."""

    kind = "no_worker"


class InternalError(ServiceError):
    """An unexpected failure (logged with its traceback)."""

    status = 500
    kind = "internal"
