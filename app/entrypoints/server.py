"""The HTTP server: uvicorn on its httptools protocol and uvloop's event loop, with the deadlines and the caps
that uvicorn's protocol lacks.

Why uvicorn and a small protocol subclass: uvicorn is the stack's server and stays; its ``http=`` setting
takes a protocol class. httptools (llhttp, the parser of Node.js) and uvloop (libuv) are the C parser and
event loop uvicorn is built to run on, in place of its pure-Python h11 protocol and asyncio's loop: less of
each exchange's fixed cost (docs/PERFORMANCE.md, "The HTTP path's share"). What uvicorn's protocol lacks:
a fresh connection that never sends (or never finishes) its headers is held forever (its keep-alive timer
only runs between requests); the parser accepts headers of any size; and ``limit_concurrency`` answers 503
only once a request's headers arrived, so silent connections still pile up until the process runs out of
file descriptors. Hypercorn's ``read_timeout`` is per read (a client trickling a byte every few seconds resets
it); granian has a header deadline, but it would replace the server and its process model for one feature.
So ``GuardedHttpToolsProtocol``:

* gives every request ``header_timeout_s`` from the connection's start (or the previous response's end) to
  deliver its headers, then answers 408 and closes;
* answers 431 and closes when a request's line and headers pass ``MAX_HEADER_BYTES`` still incomplete;
* refuses a connection beyond ``max_connections`` at once (503, closed) instead of holding it;
* the body's deadline (``body_timeout_s``) is the ASGI middleware's (``app.api.limits.BodyLimit``).

``tune_allocator`` sets the C allocator of the service process (``python -m app run``) for a long-lived
process whose requests run on many threads (see its docstring).
"""

from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import json
import logging
import resource
from typing import Any, ClassVar

import uvicorn
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from app.logs import log_config
from app.settings import Settings

__all__ = [
    "GuardedHttpToolsProtocol",
    "MAX_HEADER_BYTES",
    "guarded_protocol",
    "server_config",
    "default_max_connections",
    "tune_allocator",
    "MMAP_THRESHOLD_BYTES",
]

log = logging.getLogger("sensedispatch.server")


def default_max_connections() -> int:
    """The file descriptor limit less 64 for Redis, city files and logs (at least 16, at most 4096)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return 4096
    return max(16, min(4096, int(soft) - 64))


MAX_HEADER_BYTES = 16 * 1024
"""Bytes of a request's line and headers the server holds while they are incomplete: past them, 431. h11's
limit on an incomplete event, the same: what a client can make the server hold before its request starts
(a header block that arrives complete in one read is bounded by the read's size)."""


def _raw_response(status: int, reason: str, error: str, detail: str) -> bytes:
    body = json.dumps({"error": error, "detail": detail, "fields": []}).encode()
    head = (
        f"HTTP/1.1 {status} {reason}\r\ncontent-type: application/json\r\n"
        f"content-length: {len(body)}\r\nconnection: close\r\n\r\n"
    )
    return head.encode("ascii") + body


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a header deadline, a header size cap and a connection cap (see the
    module)."""

    header_timeout_s: ClassVar[float] = 10.0
    max_connections: ClassVar[int] = 1000
    max_header_bytes: ClassVar[int] = MAX_HEADER_BYTES

    _header_timer: asyncio.TimerHandle | None = None
    _headers_done: int = 0  # requests on this connection whose headers are complete
    _answered: int = 0  # responses this connection has completed
    _headers_pending: bool = False  # a request has begun whose headers are not complete
    _begun_in_read: int = 0  # requests begun in the read being parsed
    _header_bytes: int = 0  # bytes counted of the pending request's line and headers

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        """Count the connection; refuse it when over the cap, else start its header deadline."""
        super().connection_made(transport)
        if len(self.connections) > self.max_connections:
            log.warning("connection refused: %d open connections (SD_MAX_CONNECTIONS)", self.max_connections)
            detail = f"more than {self.max_connections} open connections; retry later"
            self._refuse(503, "Service Unavailable", "unavailable", detail)
            return
        self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        """Forget the deadline with the connection."""
        self._disarm()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        """Feed the parser; headers still incomplete past ``max_header_bytes`` are answered 431. A read
        counts whole when it holds nothing but the pending request's bytes: when the pending request began
        in it and every earlier request was answered before it, or when it began in an earlier read (a
        request pipelined behind one in flight: its headers arrive while the other is served)."""
        awaiting = self._awaiting_headers()
        self._begun_in_read = 0
        super().data_received(data)
        if self.transport.is_closing() or not self._headers_pending:
            return
        if self._begun_in_read == 0 or (awaiting and self._begun_in_read == 1):
            self._header_bytes += len(data)
            if self._header_bytes > self.max_header_bytes:
                detail = f"the request headers exceed {self.max_header_bytes} bytes"
                self._refuse(431, "Request Header Fields Too Large", "headers_too_large", detail)

    def on_message_begin(self) -> None:
        """A request begins: its headers are pending."""
        self._headers_pending = True
        self._begun_in_read += 1
        self._header_bytes = 0
        super().on_message_begin()

    def on_headers_complete(self) -> None:
        """The request's headers are complete: its deadline is off."""
        self._headers_done += 1
        self._headers_pending = False
        self._disarm()
        super().on_headers_complete()

    def on_response_complete(self) -> None:
        """The next request on this connection gets the same deadline for its headers."""
        self._answered += 1
        super().on_response_complete()
        if not self.transport.is_closing() and self._awaiting_headers():
            self._arm()

    def _awaiting_headers(self) -> bool:
        """Every request whose headers arrived is answered: the connection waits for the next headers."""
        return self._headers_done == self._answered

    def _refuse(self, status: int, reason: str, error: str, detail: str) -> None:
        self._disarm()
        self.transport.write(_raw_response(status, reason, error, detail))
        self.transport.close()

    def _arm(self) -> None:
        self._disarm()
        self._header_timer = self.loop.call_later(self.header_timeout_s, self._headers_late)

    def _disarm(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _headers_late(self) -> None:
        self._header_timer = None
        if self.transport.is_closing() or not self._awaiting_headers():
            return
        log.info("closing a connection that sent no complete request headers in %s s", self.header_timeout_s)
        detail = f"the request headers did not arrive within {self.header_timeout_s} s"
        self._refuse(408, "Request Timeout", "request_timeout", detail)


def guarded_protocol(header_timeout_s: float, max_connections: int) -> type[GuardedHttpToolsProtocol]:
    """A ``GuardedHttpToolsProtocol`` class with these limits (uvicorn makes one per connection)."""
    return type(
        "GuardedHttpToolsProtocol",
        (GuardedHttpToolsProtocol,),
        {"header_timeout_s": header_timeout_s, "max_connections": max_connections},
    )


def server_config(app: Any, settings: Settings, **overrides: Any) -> uvicorn.Config:
    """uvicorn's configuration for ``app`` under ``settings`` (``overrides`` win, e.g. ``port=0``)."""
    max_connections = settings.server.max_connections or default_max_connections()
    options: dict[str, Any] = {
        "host": settings.server.host,
        "port": settings.server.port,
        "http": guarded_protocol(settings.server.header_timeout_s, max_connections),
        "loop": "uvloop",
        "log_config": log_config(settings.log_level),
        "log_level": settings.log_level,
        "timeout_keep_alive": 5,
        "backlog": min(2048, max_connections),
    }
    options.update(overrides)
    return uvicorn.Config(app, **options)


MMAP_THRESHOLD_BYTES = 256 * 1024
"""Blocks at least this large are mapped on their own and unmapped when freed (``tune_allocator``)."""

_M_MMAP_THRESHOLD = -3  # mallopt's parameter number (glibc's malloc.h)


def tune_allocator(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc malloc's mmap threshold at ``threshold_bytes`` (``mallopt(M_MMAP_THRESHOLD)``); ``False``
    where the C library is not glibc's (nothing is changed).

    glibc raises the threshold each time a mapped block is freed (up to 32 MB), after which such blocks come
    from the heaps of the threads that allocate them, and a freed block in the middle of a heap stays
    resident. An epoch allocates and frees arrays of megabytes (numpy's, the searches' results, the
    response) on whichever threadpool thread serves the request, so the service's resident memory grew by
    the heaps' holes, epoch after epoch. With the threshold fixed, every block of at least 256 KiB is
    returned to the system when freed (the API process's peak under metropolitan epochs was 10-15 % lower in
    the measurements of docs/PERFORMANCE.md, "Memory of the service"); smaller blocks come from the heaps as
    before. Decisions do not depend on where memory comes from."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
        gnu = libc.gnu_get_libc_version
    except (OSError, AttributeError):
        return False
    del gnu  # present only in glibc, whose mallopt takes M_MMAP_THRESHOLD = -3
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, int(threshold_bytes)) == 1)
