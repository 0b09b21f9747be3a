"""The one error renderer: every failure becomes ``{"error", "detail", "fields"}`` with its status."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

from app.errors import (
    BadRequest,
    FieldIssue,
    InternalError,
    InvalidInput,
    MethodNotAllowed,
    NotFound,
    ServiceError,
    StoreUnavailable,
    UnsupportedMediaType,
    format_loc,
)
from app.metrics import Metrics

__all__ = ["install_error_handlers", "error_response", "from_validation_errors", "MAX_FIELDS"]

log = logging.getLogger(__name__)

MAX_FIELDS = 50  # field issues listed in one error; the detail gives the total

_SOURCES = {"body", "query", "path", "header", "cookie"}


def error_response(err: ServiceError, metrics: Metrics | None = None) -> JSONResponse:
    """Render ``err`` (and count it)."""
    if metrics is not None:
        metrics.errors.labels(kind=err.kind).inc()
    return JSONResponse(err.body(), status_code=err.status, headers=err.response_headers() or None)


def _msg(error: Mapping[str, Any]) -> str:
    msg = str(error.get("msg", "invalid"))
    return msg.removeprefix("Value error, ")


def from_validation_errors(errors: ValidationError | Sequence[Any]) -> ServiceError:
    """Turn pydantic/FastAPI validation errors into one ``ServiceError`` (400 for unparsable JSON).

    Only the first ``MAX_FIELDS`` issues are listed (a hostile body can hold a million); the detail names
    the first and counts them all.
    """
    items: Sequence[Any]
    if isinstance(errors, ValidationError):
        total = errors.error_count()
        items = errors.errors(include_url=False, include_context=True, include_input=False)
    else:
        total, items = len(errors), errors
    issues: list[FieldIssue] = []
    for error in items[:MAX_FIELDS]:
        loc = list(error.get("loc", ()))
        if error.get("type") == "json_invalid":
            ctx = error.get("ctx") or {}
            return BadRequest(
                f"the body is not valid JSON: {ctx.get('error', 'parse error')}",
                [FieldIssue("body", _msg(error))],
            )
        if loc == ["body"] and isinstance(error.get("input"), bytes | bytearray):
            # FastAPI hands over raw bytes when the Content-Type is not JSON
            return UnsupportedMediaType(
                "send the body as JSON with Content-Type: application/json",
                [FieldIssue("body", "not application/json")],
            )
        if loc and loc[0] in _SOURCES:
            loc = loc[1:]
        issues.append(FieldIssue(format_loc(loc) or "body", _msg(error)))
    first = issues[0] if issues else FieldIssue("body", "invalid")
    more = ""
    if total > len(issues):
        more = f" (and {total - 1} more; the first {len(issues)} are listed)"
    elif total > 1:
        more = f" (and {total - 1} more)"
    return InvalidInput(f"{first.loc}: {first.msg}{more}", issues)


_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")


def _allowed(request: Request) -> str:
    """The methods some route fully matches on this path (one route per method, and Starlette names only
    the first route's), for the ``Allow`` header of a 405."""
    routes = request.app.router.routes
    allowed = []
    for method in _METHODS:
        scope = {**request.scope, "method": method}
        if any(route.matches(scope)[0] is Match.FULL for route in routes):
            allowed.append(method)
    return ", ".join(allowed)


def install_error_handlers(app: FastAPI, metrics: Metrics) -> None:
    """Route every exception type through ``error_response``."""

    async def service_error(_: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, ServiceError)
        return error_response(exc, metrics)

    async def validation_error(_: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        return error_response(from_validation_errors(list(exc.errors())), metrics)

    async def http_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        err: ServiceError
        if exc.status_code == 404:
            err = NotFound("no such route")
        elif exc.status_code == 405:
            allow = _allowed(request) or (exc.headers or {}).get("Allow", "")
            err = MethodNotAllowed(f"method not allowed on this route (allowed: {allow})", allow=allow)
        elif 400 <= exc.status_code < 500:
            err = BadRequest(str(exc.detail))
        else:
            err = InternalError(str(exc.detail))
        return error_response(err, metrics)

    async def store_unavailable(request: Request, exc: Exception) -> JSONResponse:
        # where the store is (host, port) and why it failed is for the log, never for the client
        log.warning("store unreachable on %s %s: %s", request.method, request.url.path, exc)
        return error_response(StoreUnavailable("store unreachable"), metrics)

    async def unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
        return error_response(
            InternalError(f"internal error ({type(exc).__name__}); it has been logged"), metrics
        )

    app.add_exception_handler(ServiceError, service_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(StoreUnavailable, store_unavailable)
    app.add_exception_handler(Exception, unexpected)
