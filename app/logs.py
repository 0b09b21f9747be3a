"""Logging of ``python -m app run``: uvicorn's formats, with two filters on every handler.

``RateLimit`` keeps a flood of one message (a client storm, "Too many open files" from the accept loop)
to a few lines per window plus a count of what it dropped. ``RedactQuery`` blanks the values of query
parameters that look like credentials in the access log: a client that sends ``?token=...`` (which the API
ignores; tokens go in the ``Authorization`` header) must not leave it in the logs.
"""

from __future__ import annotations

import copy
import logging
import re
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["RateLimit", "RedactQuery", "log_config", "redact_query"]

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


class RateLimit(logging.Filter):
    """At most ``burst`` records of one message template per logger every ``window_s`` seconds; the next
    record let through after a dropped run says how many were dropped."""

    def __init__(self, burst: int = 5, window_s: float = 10.0, clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.burst = burst
        self.window_s = window_s
        self._clock = clock
        self._lock = threading.Lock()
        self._seen: dict[tuple[str, str], tuple[float, int, int]] = {}  # key -> (window start, sent, dropped)

    def filter(self, record: logging.LogRecord) -> bool:
        """Let the record through unless its template is over budget in the current window."""
        key = (record.name, str(record.msg))
        now = self._clock()
        with self._lock:
            start, sent, dropped = self._seen.get(key, (now, 0, 0))
            if now - start >= self.window_s:
                start, sent = now, 0
            if sent >= self.burst:
                self._seen[key] = (start, sent, dropped + 1)
                return False
            self._seen[key] = (start, sent + 1, 0)
            if len(self._seen) > 10_000:  # many distinct templates: forget the oldest windows
                for old in sorted(self._seen, key=lambda k: self._seen[k][0])[:5_000]:
                    del self._seen[old]
        if dropped:
            record.msg = f"[{dropped} similar messages suppressed] {record.msg}"
        return True


def log_config(level: str) -> dict[str, Any]:
    """The ``logging.config.dictConfig`` of the server: uvicorn's handlers and formats, our app loggers on
    the same stream, every handler rate-limited, the access log redacted."""
    from uvicorn.config import LOGGING_CONFIG

    config = copy.deepcopy(LOGGING_CONFIG)
    config["filters"] = {
        "rate": {"()": RateLimit},
        "redact": {"()": RedactQuery},
    }
    config["handlers"]["default"]["filters"] = ["rate"]
    config["handlers"]["access"]["filters"] = ["redact", "rate"]
    config["formatters"]["app"] = {"format": "%(asctime)s %(levelname)s %(name)s: %(message)s"}
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
