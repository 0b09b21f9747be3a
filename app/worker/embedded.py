"""The fleet worker inside the API process (``python -m app run`` on the memory store; docs/FLEET.md).

On the embedded default the store is this process's memory, so no other process could solve: the service
runs the worker itself, scheduled exactly as a ``python -m app worker`` on Redis is (before every hour of
the horizon, plus queued requests), on the same store. Its heartbeat starts at once, so a solve request
made during start-up is queued; its loop starts when the warm-up has finished. The simulation runs execute
on local processes with a raised niceness (``SD_WORKER_NICE``), never in this process, so that epochs keep
the CPU; only the sizing itself (worst cases over the runs' samples, well under a second) runs on the
worker's thread here. ``app.bootstrap.embedded_worker`` builds it.
"""

from __future__ import annotations

import threading

from app.runs import ProcessExecutor
from app.worker.service import AssembledWorker

__all__ = ["EmbeddedWorker"]


class EmbeddedWorker:
    """A fleet worker (``parts``) on a thread of this process, for the app's lifetime."""

    def __init__(self, parts: AssembledWorker, *, ready: threading.Event | None = None) -> None:
        """``ready`` is set when the warm-up is over: the loop starts then."""
        self.parts = parts
        self.ready = ready
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start beating now and solving once the warm-up is over."""
        self.parts.heartbeat.start()
        self._thread = threading.Thread(target=self._run, name="fleet-worker", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self.ready is not None:
            while not self.ready.wait(0.5):
                if self._stop.is_set():
                    return
        self.parts.worker.run(self._stop)

    def stop(self, grace_s: float = 2.0, timeout_s: float = 10.0) -> None:
        """Stop the loop and the heartbeat, and close the run processes. A loop still busy after
        ``grace_s`` is in a solve: its runs are abandoned (the process is ending; a metropolitan run lasts
        minutes) and the loop is given ``timeout_s`` more to see them fail."""
        self._stop.set()
        self.parts.heartbeat.stop()
        if self._thread is not None:
            self._thread.join(timeout=grace_s)
            executor = self.parts.runner.executor
            if self._thread.is_alive() and isinstance(executor, ProcessExecutor):
                executor.abandon()
                self._thread.join(timeout=timeout_s)
        self.parts.runner.close()
