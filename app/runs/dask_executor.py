"""Runs on a Dask distributed cluster (``SD_WORKER_EXECUTOR=dask``, ``SD_DASK_SCHEDULER=tcp://host:8786``).

Dask is the engine; this module only adapts it to the ``Executor`` seam (docs/FLEET.md, "Cluster"):

* every item is one task named by its key, so clients that submit the same run share one computation;
* a task whose worker dies is rerun on another worker by the scheduler (``allowed-failures``); a task that
  raises is not retried (runs are pure: it would raise again);
* each city bundle reaches every worker once, as a worker plugin (workers that join later get it too);
* a task reports its start and end as ``sd-run`` events, so the runner can show what runs where;
* a lost scheduler fails the pending items at once, and the next batch reconnects (or says it cannot).
"""

from __future__ import annotations

import logging
import os
import queue
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import CancelledError
from pathlib import Path
from typing import Any, TypeVar

from distributed import Client, Future, get_worker
from distributed.diagnostics.plugin import WorkerPlugin

from app.runs.bundles import BundleFiles, install_shipped
from app.runs.executor import Event, ExecutorUnavailable, Finished, Started, reason

__all__ = ["DaskExecutor", "BundlePlugin", "TOPIC"]

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")

TOPIC = "sd-run"
"""The event topic on which a task says it started or ended: ``{"key", "state", "worker", "pid"}``."""


class BundlePlugin(WorkerPlugin):
    """Writes one city bundle into each worker's local directory (``open_bundle`` then reads that copy)."""

    idempotent = True  # registered again under the same name (same digest): nothing to do

    def __init__(self, bundle: BundleFiles) -> None:
        self.bundle = bundle

    def setup(self, worker: Any) -> None:
        """Install the bundle on ``worker``."""
        install_shipped(self.bundle, Path(worker.local_directory) / "sd-bundles")


def _report_then(fn: Callable[[T], R], item: T) -> R:
    """On a Dask worker: announce the start of the current task, run it, announce its end."""
    worker = get_worker()
    msg = {"key": worker.get_current_task(), "worker": worker.address, "pid": os.getpid()}
    worker.log_event(TOPIC, {**msg, "state": "started"})
    try:
        return fn(item)
    finally:
        worker.log_event(TOPIC, {**msg, "state": "ended"})


class DaskExecutor:
    """Items as tasks on the Dask cluster whose scheduler is at ``address``.

    Connects on first use (``timeout_s`` bounds the connection and the wait for a first worker) and keeps
    the connection; ``fn`` and the items travel by pickle, so ``fn`` must be importable on the workers.
    """

    def __init__(self, address: str, *, timeout_s: float = 10.0) -> None:
        self.address = address
        self.timeout_s = timeout_s
        self._client: Client | None = None
        self._threads = 0
        self._shipped: set[str] = set()
        self._events: queue.SimpleQueue[dict[str, Any]] = queue.SimpleQueue()

    @property
    def workers(self) -> int:
        """Worker threads of the cluster at the last batch (0 before the first)."""
        return self._threads

    @property
    def dashboard(self) -> str | None:
        """The scheduler's dashboard, once connected."""
        return None if self._client is None else str(self._client.dashboard_link)

    def _connect(self) -> Client:
        if self._client is not None and self._client.status == "running":
            return self._client
        self.close()
        try:
            client = Client(self.address, timeout=self.timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise ExecutorUnavailable(f"cannot reach the Dask scheduler at {self.address}: {exc}") from exc
        try:
            client.wait_for_workers(1, timeout=self.timeout_s)
        except (OSError, TimeoutError) as exc:
            client.close()
            raise ExecutorUnavailable(
                f"the Dask scheduler at {self.address} has no workers (waited {self.timeout_s:g} s)"
            ) from exc
        client.subscribe_topic(TOPIC, self._event)
        self._client = client
        log.info("connected to the Dask scheduler at %s (dashboard %s)", self.address, client.dashboard_link)
        return client

    def _event(self, event: tuple[float, dict[str, Any]]) -> None:
        self._events.put(event[1])  # called on the client's event loop thread

    def ship(self, bundle: Path) -> None:
        """Register the bundle's plugin (once per content digest and connection)."""
        files = BundleFiles.read(bundle)
        name = f"sd-bundle-{files.digest[:16]}"
        client = self._connect()
        if name in self._shipped:
            return
        try:
            client.register_plugin(BundlePlugin(files), name=name)
        except (OSError, TimeoutError, CancelledError) as exc:
            self.close()
            raise ExecutorUnavailable(
                f"could not ship {bundle.name} to the Dask cluster at {self.address}: {reason(exc)}"
            ) from exc
        log.info("shipped city bundle %s (%d bytes) to the Dask workers", bundle.name, files.size_bytes)
        self._shipped.add(name)

    def map_unordered(
        self, fn: Callable[[T], R], items: Sequence[T], keys: Sequence[str] | None = None
    ) -> Iterator[Event[R]]:
        """Submit every item as a task (named ``keys[i]`` when given), yield starts and outcomes."""
        if not items:
            return
        client = self._connect()
        self._threads = sum(int(w["nthreads"]) for w in client.scheduler_info()["workers"].values())
        futures: list[Future[R]] = client.map(
            _report_then, [fn] * len(items), items, key=list(keys) if keys else None, pure=False, retries=0
        )
        pending = {f.key: i for i, f in enumerate(futures)}
        ended: set[Any] = set()  # pending keys whose task said it ended: their outcome is on its way
        held: list[dict[str, Any]] = []  # starts that wait for those outcomes (a worker's next task)
        lost = False
        try:
            while pending:
                try:
                    msgs = [self._events.get(timeout=0.05)]
                    while not self._events.empty():
                        msgs.append(self._events.get())
                except queue.Empty:
                    msgs = []
                for msg in msgs:
                    if msg["key"] not in pending:
                        continue  # another batch's or another client's task
                    if msg["state"] == "ended":
                        ended.add(msg["key"])
                    else:
                        ended.discard(msg["key"])  # started again: its worker died before the outcome
                        held.append(msg)
                for key, i in list(pending.items()):
                    fut = futures[i]
                    if not fut.done():
                        continue
                    del pending[key]
                    try:
                        value = fut.result()
                    except CancelledError as exc:
                        lost = lost or self._client is None or self._client.status != "running"
                        why = f"the Dask scheduler at {self.address} was lost" if lost else "cancelled"
                        yield Finished(i, error=f"{why} ({reason(exc).splitlines()[0]})")
                    except Exception as exc:  # noqa: BLE001 - one failed item is reported, the others go on
                        yield Finished(i, error=reason(exc))
                    else:
                        yield Finished(i, value)
                ended &= pending.keys()
                if not ended:  # every outcome before the starts that followed it
                    for msg in held:
                        if msg["key"] in pending:
                            yield Started(pending[msg["key"]], str(msg["worker"]), int(msg["pid"]))
                    held.clear()
        finally:
            del futures  # released: a task no other client wants is forgotten by the scheduler
            if lost:
                self.close()

    def close(self) -> None:
        """Disconnect (the cluster goes on; the next batch connects again)."""
        client, self._client = self._client, None
        self._shipped.clear()
        if client is not None:
            try:
                client.close(timeout=self.timeout_s)
            except (OSError, TimeoutError, RuntimeError) as exc:
                log.warning("closing the Dask client of %s: %s", self.address, exc)
