"""Logging of ``python -m app run``: uvicorn's formats, with two filters on every handler.

``RateLimit`` keeps a flood of one message ("Too many open files" from the accept loop) to a few lines per
window, and ``AccessRateLimit`` one client's storm of requests of one status class to a budget that a
platform's traffic never reaches; the next line kept says how many were dropped. ``RedactQuery`` blanks
the values of query parameters that look like credentials in the access log: a client that sends
``?token=...`` (which the API ignores; tokens go in the ``Authorization`` header) must not leave it in the
logs.
"""

from __future__ import annotations

import copy
import logging
import re
import threading
import time
from collections.abc import Callable
from typing import Any

import uvicorn.logging

__all__ = [
    "RateLimit",
    "AccessRateLimit",
    "RedactQuery",
    "DefaultFormatter",
    "AccessFormatter",
    "AppFormatter",
    "log_config",
    "redact_query",
]

_SECRET_NAMES = re.compile(
    r"(?i)^(token|access_token|id_token|refresh_token|api_key|apikey|key|auth|authorization|bearer|"
    r"password|passwd|secret|client_secret|signature|sig|session)$"
)
_QUERY_PAIR = re.compile(r"([^&=?]+)=([^&]*)")


def redact_query(path: str) -> str:
    """``path`` with the values of credential-like query parameters replaced by ``***``."""
    base, sep, query = path.partition("?")
    if not sep:
        return path

    def blank(m: re.Match[str]) -> str:
        return f"{m.group(1)}=***" if _SECRET_NAMES.match(m.group(1)) else m.group(0)

    return base + sep + _QUERY_PAIR.sub(blank, query)


class RedactQuery(logging.Filter):
    """Blank credential-like query values in uvicorn's access records (the path is their third arg)."""

    def filter(self, record: logging.LogRecord) -> bool:
        """Rewrite the record's path argument; never drops a record."""
        args = record.args
        if isinstance(args, tuple) and len(args) >= 3 and isinstance(args[2], str):
            record.args = (*args[:2], redact_query(args[2]), *args[3:])
        return True


_NOTE = "suppressed"  # the record attribute the formatters append (empty when nothing was dropped)


class RateLimit(logging.Filter):
    """At most ``burst`` records of one key every ``window_s`` seconds; the next record of that key let
    through says how many were dropped (the formatters of :func:`log_config` append ``record.suppressed``).

    The key is what repeats in a flood: :meth:`key` is the logger and the formatted message, so the same
    template with other arguments ("fleet chengdu ..." and "fleet manhattan ...") is not one flood.
    """

    noun = "identical messages"

    def __init__(self, burst: int = 5, window_s: float = 10.0, clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.burst = burst
        self.window_s = window_s
        self._clock = clock
        self._lock = threading.Lock()
        self._seen: dict[tuple[str, ...], tuple[float, int, int]] = {}  # key -> (window start, sent, dropped)

    def key(self, record: logging.LogRecord) -> tuple[str, ...]:
        """What a flood repeats: the logger and the message as it would be shown."""
        return (record.name, record.getMessage())

    def filter(self, record: logging.LogRecord) -> bool:
        """Let the record through unless its key is over budget in the current window."""
        key = self.key(record)
        now = self._clock()
        with self._lock:
            start, sent, dropped = self._seen.get(key, (now, 0, 0))
            if now - start >= self.window_s:
                start, sent = now, 0
            if sent >= self.burst:
                self._seen[key] = (start, sent, dropped + 1)
                return False
            self._seen[key] = (start, sent + 1, 0)
            if len(self._seen) > 10_000:  # many distinct keys: forget the oldest windows
                for old in sorted(self._seen, key=lambda k: self._seen[k][0])[:5_000]:
                    del self._seen[old]
        setattr(record, _NOTE, f" [{dropped} {self.noun} suppressed]" if dropped else "")
        return True


class AccessRateLimit(RateLimit):
    """The access log's flood guard: keyed on the client's address and the response's status class, so one
    client's storm of failing requests is cut down while every other request is logged. The default budget,
    500 records per client and class every 10 s, is far above what a platform sends (an epoch every few
    seconds per city, dashboards polling every few seconds, metrics scrapes)."""

    noun = "similar requests"

    def __init__(self, burst: int = 500, window_s: float = 10.0, clock: Callable[[], float] = time.monotonic):
        super().__init__(burst, window_s, clock)

    def key(self, record: logging.LogRecord) -> tuple[str, ...]:
        """The client's host (without its port) and the status class, e.g. ``("127.0.0.1", "4xx")``."""
        args = record.args
        if not (isinstance(args, tuple) and len(args) >= 5):
            return super().key(record)
        host = str(args[0]).rpartition(":")[0] or str(args[0])
        return (host, f"{str(args[4])[:1]}xx")


class _Noted:
    """Appends a record's suppressed-count note to the line the formatter built."""

    def format(self, record: logging.LogRecord) -> str:
        line: str = super().format(record)  # type: ignore[misc]
        return line + str(getattr(record, _NOTE, ""))


class DefaultFormatter(_Noted, uvicorn.logging.DefaultFormatter):
    """uvicorn's default format, with the count of dropped records when there is one."""


class AccessFormatter(_Noted, uvicorn.logging.AccessFormatter):
    """uvicorn's access format, with the count of dropped records when there is one."""


class AppFormatter(_Noted, logging.Formatter):
    """The application loggers' format, with the count of dropped records when there is one."""


def log_config(level: str) -> dict[str, Any]:
    """The ``logging.config.dictConfig`` of the server: uvicorn's handlers and formats, our app loggers on
    the same stream, every handler guarded against floods (the access log per client and status class,
    the others per message), the access log redacted."""
    from uvicorn.config import LOGGING_CONFIG

    config = copy.deepcopy(LOGGING_CONFIG)
    config["filters"] = {
        "rate": {"()": RateLimit},
        "access_rate": {"()": AccessRateLimit},
        "redact": {"()": RedactQuery},
    }
    config["formatters"]["default"]["()"] = DefaultFormatter
    config["formatters"]["access"]["()"] = AccessFormatter
    config["formatters"]["app"] = {
        "()": AppFormatter,
        "format": "%(asctime)s %(levelname)s %(name)s: %(message)s",
    }
    config["handlers"]["default"]["filters"] = ["rate"]
    config["handlers"]["access"]["filters"] = ["redact", "access_rate"]
    config["handlers"]["app"] = {
        "class": "logging.StreamHandler",
        "formatter": "app",
        "stream": "ext://sys.stderr",
        "filters": ["rate"],
    }
    config["root"] = {"handlers": ["app"], "level": level.upper()}
    for name in ("uvicorn", "uvicorn.error", "uvicorn.access"):
        config["loggers"].setdefault(name, {})["level"] = level.upper()
    return config
