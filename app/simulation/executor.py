"""Where runs execute: the seam between the runner (cache, order, progress) and the machinery that runs
them. ``InlineExecutor`` runs in this process, ``ProcessExecutor`` on local worker processes; a distributed
engine plugs in behind the same ``Executor`` protocol (``make_executor`` picks one by name)."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Generic, Literal, Protocol, TypeVar

__all__ = ["Finished", "Executor", "InlineExecutor", "ProcessExecutor", "ExecutorName", "make_executor"]

T = TypeVar("T")
R = TypeVar("R")

ExecutorName = Literal["local"]


@dataclass(frozen=True, slots=True)
class Finished(Generic[R]):
    """One finished item: its position in the submitted sequence and its value, or why it failed."""

    index: int
    value: R | None = None
    error: str | None = None


class Executor(Protocol):
    """Runs a function over items and yields each outcome as it finishes (in any order)."""

    @property
    def workers(self) -> int:
        """How many items run at once."""

    def map_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[Finished[R]]:
        """``fn(item)`` for every item; an item that raises yields its error, the others go on."""

    def close(self) -> None:
        """Release the workers (the executor may be used again afterwards)."""


def _reason(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


class InlineExecutor:
    """Runs every item in this process, one after the other."""

    workers = 1

    def map_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[Finished[R]]:
        """Call ``fn`` on each item in order."""
        for i, item in enumerate(items):
            try:
                value = fn(item)
            except Exception as exc:  # noqa: BLE001 - one failed item is reported, the others go on
                yield Finished(i, error=_reason(exc))
            else:
                yield Finished(i, value)

    def close(self) -> None:
        """Nothing to release."""


class ProcessExecutor:
    """Runs items on ``workers`` local processes (forkserver: no state of this process leaks into them).

    The pool starts on the first call that needs it and is kept for later ones; a broken pool (a worker
    process died) fails the items it held and is started again next time. ``fn`` must be a module-level
    function (it is sent to the processes by name).
    """

    def __init__(self, workers: int = 2) -> None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self._workers = workers
        self._pool: ProcessPoolExecutor | None = None

    @property
    def workers(self) -> int:
        """The number of processes."""
        return self._workers

    def map_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[Finished[R]]:
        """Submit every item, yield them as they finish."""
        if not items:
            return
        if self._pool is None:
            ctx = multiprocessing.get_context("forkserver")
            self._pool = ProcessPoolExecutor(max_workers=self._workers, mp_context=ctx)
        futures: dict[Future[R], int] = {self._pool.submit(fn, item): i for i, item in enumerate(items)}
        broken = False
        try:
            for fut in as_completed(futures):
                try:
                    value = fut.result()
                except BrokenProcessPool as exc:
                    broken = True
                    yield Finished(futures[fut], error=_reason(exc))
                except Exception as exc:  # noqa: BLE001 - as in InlineExecutor
                    yield Finished(futures[fut], error=_reason(exc))
                else:
                    yield Finished(futures[fut], value)
        finally:
            if broken:
                self.close()

    def close(self) -> None:
        """Stop the processes."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def make_executor(workers: int, name: ExecutorName = "local") -> Executor:
    """The executor a configuration names: ``local`` runs in this process with one worker, else on
    ``workers`` local processes."""
    if name != "local":
        raise ValueError(f"unknown executor {name!r}")
    return InlineExecutor() if workers == 1 else ProcessExecutor(workers)
