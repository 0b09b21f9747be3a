"""The cyclic garbage collector kept out of epoch exchanges: collected after the response, not during it.

An epoch allocates hundreds of thousands of objects (the parsed body, the snapshot, the decision, the
response's documents), enough to pass the service's thresholds (``app.api.warmup.GC_THRESHOLD``) a few
times an exchange, each pass walking every young object. Almost all of them are freed by reference
counting as the exchange ends; what the collector finds is rarely garbage. So while
an epoch post is in flight (``EpochForeground`` holds ``CollectorDeferral.held`` from its headers to its
response handed to the server) the collector is off; when the last exchange in flight ends it is on again,
and the first allocation after that runs the collection its counts are due, by its own rules, on the
thread that ended the exchange. Nothing of a decision depends on when cycles are collected; the deferral
moves the collector's work out of the latency a platform sees.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["CollectorDeferral"]


class CollectorDeferral:
    """Holds the collector off while any held exchange is in flight (a count under a lock: holds overlap
    across threads and tasks); the last one out turns it on again, unless it was off before the first."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._in_flight = 0
        self._was_enabled = True

    @contextmanager
    def held(self) -> Iterator[None]:
        """The collector off for the duration."""
        with self._lock:
            self._in_flight += 1
            if self._in_flight == 1:
                self._was_enabled = gc.isenabled()
                gc.disable()
        try:
            yield
        finally:
            with self._lock:
                self._in_flight -= 1
                if self._in_flight == 0 and self._was_enabled:
                    gc.enable()
