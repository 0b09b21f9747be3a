"""Where runs execute: the seam between the runner (cache, order, progress) and the machinery that runs them.
``InlineExecutor`` runs in this process, ``ProcessExecutor`` on local worker processes and ``DaskExecutor``
(``app.runs.dask_executor``) on a Dask distributed cluster reached by address; ``make_executor``
(``app.runs.factory``) picks one by name. Each reports when an item starts (``Started``, again when the
engine reruns it elsewhere) and when it finishes (``Finished``)."""

from __future__ import annotations

import itertools
import multiprocessing
import os
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, Literal, Protocol, TypeVar

__all__ = [
    "Started",
    "Finished",
    "Event",
    "Executor",
    "ExecutorUnavailable",
    "InlineExecutor",
    "ProcessExecutor",
    "ExecutorName",
    "Foreground",
]

T = TypeVar("T")
R = TypeVar("R")

ExecutorName = Literal["local", "dask"]


@dataclass(frozen=True, slots=True)
class Started:
    """An item began on a worker (``worker`` names it: a Dask worker's address, else ``pid N``). An item
    the engine reruns after its worker died starts again."""

    index: int
    worker: str
    pid: int


@dataclass(frozen=True, slots=True)
class Finished(Generic[R]):
    """One finished item: its position in the submitted sequence and its value, or why it failed."""

    index: int
    value: R | None = None
    error: str | None = None


Event = Started | Finished[R]


class ExecutorUnavailable(RuntimeError):
    """The executor cannot run anything now (e.g. its cluster's scheduler is unreachable)."""


class Executor(Protocol):
    """Runs a function over items and yields each item's start and outcome as they happen (in any order)."""

    @property
    def workers(self) -> int:
        """How many items run at once."""

    def ship(self, bundle: Path) -> None:
        """Make the city bundle at ``bundle`` (an absolute path) readable by every worker under that path."""

    def map_unordered(
        self, fn: Callable[[T], R], items: Sequence[T], keys: Sequence[str] | None = None
    ) -> Iterator[Event[R]]:
        """``fn(item)`` for every item; an item that raises yields its error, the others go on. ``keys``
        name the items (unique; an engine shares one computation among the clients that submit a key).

        Raises ``ExecutorUnavailable`` when nothing can run."""

    def close(self) -> None:
        """Release the workers (the executor may be used again afterwards)."""


def reason(exc: BaseException) -> str:
    """How a failure reads in a batch's failures."""
    return f"{type(exc).__name__}: {exc}"


class InlineExecutor:
    """Runs every item in this process, one after the other."""

    workers = 1

    def ship(self, bundle: Path) -> None:
        """Nothing to ship: this process reads the bundle itself."""

    def map_unordered(
        self, fn: Callable[[T], R], items: Sequence[T], keys: Sequence[str] | None = None
    ) -> Iterator[Event[R]]:
        """Call ``fn`` on each item in order."""
        pid = os.getpid()
        for i, item in enumerate(items):
            yield Started(i, f"pid {pid}", pid)
            try:
                value = fn(item)
            except Exception as exc:  # noqa: BLE001 - one failed item is reported, the others go on
                yield Finished(i, error=reason(exc))
            else:
                yield Finished(i, value)

    def close(self) -> None:
        """Nothing to release."""


_started: Any = None  # in a pool process: the queue it reports starts on (set by _init_pool_process)


START_WAIT_S = 5.0
"""How long an outcome waits for its item's start to come through the queue."""


def _watch_service(service_pid: int) -> None:
    """In a pool process: end this process once the service that started the pool has ended, so a service
    killed mid-solve leaves no simulation running on without it (the forkserver between them lives as long
    as its children do, so the kernel's parent-death signal would never come)."""

    def watch() -> None:
        while True:
            time.sleep(1.0)
            try:
                os.kill(service_pid, 0)
            except ProcessLookupError:
                os._exit(1)
            except PermissionError:  # the pid was taken by another user's process: ours has ended
                os._exit(1)

    threading.Thread(target=watch, name="watch-service", daemon=True).start()


def _init_pool_process(started: Any, nice: int, service_pid: int) -> None:
    global _started
    _started = started
    _watch_service(service_pid)
    if nice > 0:
        os.nice(nice)  # the runs yield the CPU to the service's epochs (CFS weighs nice 10 at ~1/10)


def _report_then(fn: Callable[[T], R], tag: tuple[int, int], item: T) -> R:
    """In a pool process: say that item ``tag`` = (batch, index) starts, then run it."""
    if _started is not None:
        _started.put((*tag, os.getpid()))
    return fn(item)


class ProcessExecutor:
    """Runs items on ``workers`` local processes (forkserver: no state of this process leaks into them).

    The pool starts on the first call that needs it and is kept for later ones; a broken pool (a worker
    process died) fails the items it held and is started again next time. ``fn`` must be a module-level
    function (it is sent to the processes by name). The processes read bundles from this machine's disk.
    ``nice`` is added to each process's niceness when it starts (0..19), so that the runs of a worker
    inside the API process leave the CPU to the epochs. A process ends by itself within a second of the
    process that started the pool ending (killed, say): no run goes on without its service.
    """

    def __init__(self, workers: int = 2, *, nice: int = 0) -> None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        if not 0 <= nice <= 19:
            raise ValueError(f"nice must lie in 0..19, got {nice}")
        self._workers = workers
        self._nice = nice
        self._pool: ProcessPoolExecutor | None = None
        self._started: Any = None
        self._batches = itertools.count()
        self._paused = False
        self._signal_lock = threading.Lock()

    def _pids(self) -> list[int]:
        """The pool's live processes (none before the first batch)."""
        pool = self._pool
        procs = dict(getattr(pool, "_processes", None) or {}) if pool is not None else {}
        return [pid for pid, p in procs.items() if p.is_alive()]

    def _signal_all(self, sig: signal.Signals) -> None:
        for pid in self._pids():
            try:
                os.kill(pid, sig)
            except ProcessLookupError:  # it ended meanwhile
                continue

    def pause(self) -> None:
        """Stop the processes where they are (SIGSTOP) until :meth:`resume`: their runs take no CPU, and
        a process the pool starts meanwhile is stopped as the next batch submits its items."""
        with self._signal_lock:
            self._paused = True
            self._signal_all(signal.SIGSTOP)

    def resume(self) -> None:
        """Let the processes run on (SIGCONT)."""
        with self._signal_lock:
            self._paused = False
            self._signal_all(signal.SIGCONT)

    @property
    def workers(self) -> int:
        """The number of processes."""
        return self._workers

    def ship(self, bundle: Path) -> None:
        """Nothing to ship: the processes read this machine's disk."""

    def map_unordered(
        self, fn: Callable[[T], R], items: Sequence[T], keys: Sequence[str] | None = None
    ) -> Iterator[Event[R]]:
        """Submit every item, yield their starts and outcomes as they happen."""
        if not items:
            return
        if self._pool is None:
            ctx = multiprocessing.get_context("forkserver")
            self._started = ctx.Queue()
            self._pool = ProcessPoolExecutor(
                max_workers=self._workers,
                mp_context=ctx,
                initializer=_init_pool_process,
                initargs=(self._started, self._nice, os.getpid()),
            )
        batch = next(self._batches)
        pool, started = self._pool, self._started
        futures: dict[Future[R], int] = {
            pool.submit(_report_then, fn, (batch, i), item): i for i, item in enumerate(items)
        }
        with self._signal_lock:
            if self._paused:  # processes the submissions started
                self._signal_all(signal.SIGSTOP)
        pending = set(futures)
        broken = False
        seen: set[int] = set()
        try:
            while pending:
                done, pending = wait(pending, timeout=0.05, return_when=FIRST_COMPLETED)
                while True:  # the starts so far, before the outcomes that follow them
                    try:
                        b, i, pid = started.get_nowait()
                    except queue.Empty:
                        break
                    if b == batch and i not in seen:
                        seen.add(i)
                        yield Started(i, f"pid {pid}", pid)
                for fut in done:
                    # an item's start is put on the queue before it runs, but the queue's feeder thread
                    # may deliver it after the outcome: wait for it (not for an item a dead process held)
                    deadline = time.monotonic() + START_WAIT_S
                    dead = isinstance(fut.exception(), BrokenProcessPool)
                    while futures[fut] not in seen and not dead:
                        try:
                            b, i, pid = started.get(timeout=max(0.0, deadline - time.monotonic()))
                        except queue.Empty:
                            break
                        if b == batch and i not in seen:
                            seen.add(i)
                            yield Started(i, f"pid {pid}", pid)
                    try:
                        value = fut.result()
                    except BrokenProcessPool as exc:
                        broken = True
                        yield Finished(futures[fut], error=reason(exc))
                    except Exception as exc:  # noqa: BLE001 - as in InlineExecutor
                        yield Finished(futures[fut], error=reason(exc))
                    else:
                        yield Finished(futures[fut], value)
        finally:
            if broken:
                self.close()

    def abandon(self) -> None:
        """End the processes now, the runs in progress lost (their service is ending): the batch being
        mapped fails what they held, and ``close`` then waits for no run."""
        with self._signal_lock:
            for pid in self._pids():
                for sig in (signal.SIGTERM, signal.SIGCONT):  # a stopped process takes the first when resumed
                    try:
                        os.kill(pid, sig)
                    except ProcessLookupError:
                        break

    def close(self) -> None:
        """Stop the processes once their runs in progress are over (``abandon`` first not to wait)."""
        self.resume()  # a stopped process would never take its shutdown
        with self._signal_lock:
            pool, started = self._pool, self._started
            self._pool = self._started = None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
            started.close()


class Foreground:
    """Epochs come first: while any epoch is being solved, the background runs of the processes added here
    are paused (the first epoch to start pauses them, the last to end resumes them; holds nest). The service
    that embeds the fleet worker holds it around every epoch post's whole exchange (headers to response,
    ``app.api.foreground``), so the worker's simulations use the CPU only between epochs (docs/FLEET.md,
    "When the worker solves")."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._in_flight = 0
        self._executors: list[ProcessExecutor] = []

    def add(self, executor: ProcessExecutor) -> None:
        """Pause ``executor``'s processes while epochs are in flight."""
        with self._lock:
            self._executors.append(executor)
            if self._in_flight:
                executor.pause()

    @contextmanager
    def epoch(self) -> Iterator[None]:
        """Hold for one epoch's solve."""
        with self._lock:
            self._in_flight += 1
            if self._in_flight == 1:
                for ex in self._executors:
                    ex.pause()
        try:
            yield
        finally:
            with self._lock:
                self._in_flight -= 1
                if self._in_flight == 0:
                    for ex in self._executors:
                        ex.resume()
