"""Finished runs by job key: the ``ResultCache`` port and its disk implementation (``RunCache``); the Redis
one, shared by every fleet worker, is ``app.adapters.run_cache.RedisRunCache``."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Protocol

from app.runs.result import RunResult

__all__ = ["ResultCache", "RunCache"]

log = logging.getLogger(__name__)


class ResultCache(Protocol):
    """Where the runner keeps finished runs (a run is a pure function of its key: never simulated twice)."""

    def get(self, key: str) -> RunResult | None:
        """The cached run, or ``None`` (an unreadable entry counts as missing and is logged)."""

    def put(self, result: RunResult) -> None:
        """Store a run under ``result.key`` (a reader never sees half of it)."""


class RunCache:
    """Finished runs as ``<dir>/<key>.json`` (written to a temporary file, then renamed)."""

    def __init__(self, directory: Path) -> None:
        """Cache under ``directory`` (created on the first write)."""
        self.directory = directory

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.json"

    def get(self, key: str) -> RunResult | None:
        """The cached run, or ``None`` (an unreadable file counts as missing and is logged)."""
        path = self._path(key)
        try:
            return RunResult.from_json(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("ignoring unreadable cached run %s: %r", path, exc)
            return None

    def put(self, result: RunResult) -> None:
        """Store a run atomically."""
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self._path(result.key)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(result.to_json(), encoding="utf-8")
        tmp.replace(path)
