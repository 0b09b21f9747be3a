"""The fleet worker inside the API process (``python -m app run`` on the memory store; docs/FLEET.md).

On the embedded default the store is this process's memory, so no other process could solve: the service
runs the worker itself, scheduled exactly as a ``python -m app worker`` on Redis is (before every hour of
the horizon, plus queued requests), on the same store. Its heartbeat starts at once, so a solve request
made during start-up is queued; its loop starts when the warm-up has finished. The simulation runs execute
on local processes with a raised niceness (``SD_WORKER_NICE``), never in this process, so that epochs keep
the CPU; only the sizing itself (worst cases over the runs' samples, well under a second) runs on the
worker's thread here.
"""

from __future__ import annotations

import logging
import threading

from app.adapters.cities import CityRegistry
from app.ports import Store
from app.runs.executor import Foreground
from app.settings import Settings
from app.usecases import CityCatalog
from app.worker.assembly import AssembledWorker, assemble_worker, worker_cities

__all__ = ["EmbeddedWorker"]

log = logging.getLogger(__name__)


class EmbeddedWorker:
    """A fleet worker on a thread of this process, for the app's lifetime."""

    def __init__(
        self,
        settings: Settings,
        store: Store,
        registry: CityCatalog,
        *,
        ready: threading.Event | None = None,
        foreground: Foreground | None = None,
    ) -> None:
        """``registry`` serves the cities (a ``CityRegistry`` also gives the bundles the runs read; any
        other catalog is replaced by the settings' registry); ``ready`` is set when the warm-up is over;
        ``foreground`` (the API's epochs) pauses the worker's runs while an epoch is solved."""
        self.settings = settings
        self.store = store
        self.registry = (
            registry if isinstance(registry, CityRegistry) else CityRegistry.from_settings(settings)
        )
        self.ready = ready
        self.foreground = foreground
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.parts: AssembledWorker | None = None

    def start(self) -> None:
        """Start beating now and solving once the warm-up is over (an unknown city in SD_WORKER_CITIES is
        logged and no worker starts: the API then answers solve requests with 503 no_worker)."""
        cities, unknown = worker_cities(self.settings, self.registry)
        if unknown:
            log.error(
                "fleet worker not started: unknown cities %s in SD_WORKER_CITIES; served: %s",
                unknown,
                self.registry.names(),
            )
            return
        self.parts = assemble_worker(
            self.settings, self.store, self.registry, cities, embedded=True, foreground=self.foreground
        )
        self.parts.heartbeat.start()
        self._thread = threading.Thread(target=self._run, name="fleet-worker", daemon=True)
        self._thread.start()
        log.info(
            "fleet worker running in this process for %s (simulation runs on %d local process(es) at "
            "niceness +%d)",
            ", ".join(cities),
            max(1, self.settings.worker_jobs),
            self.settings.worker_nice,
        )

    def _run(self) -> None:
        assert self.parts is not None
        if self.ready is not None:
            while not self.ready.wait(0.5):
                if self._stop.is_set():
                    return
        self.parts.worker.run(self._stop)

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop the loop after its current step (a solve in progress is abandoned when it outlasts
        ``timeout_s``: the process is ending) and the heartbeat; close the run processes."""
        self._stop.set()
        if self.parts is None:
            return
        self.parts.heartbeat.stop()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
        self.parts.runner.close()
