"""Resident memory of a process and of its whole tree (its children, theirs, ...), read from Linux's /proc.

``TreePeak`` samples a process tree on a thread while a benchmark drives it: the peak of the process itself
is its ``VmHWM`` (the kernel's exact high-water mark), the tree's is the largest sum of ``VmRSS`` over the
processes alive at one sample. Pages shared between processes (a forked child's untouched pages, shared
libraries) count once per process, so the tree's figure is what ``ps`` would add up; a spike shorter than
the sampling interval can be missed.
"""

from __future__ import annotations

import threading
from pathlib import Path
from types import TracebackType

__all__ = ["TreePeak", "descendants", "rss_mb", "hwm_mb"]


def _status_mb(pid: int, field: str) -> float:
    """A ``kB`` field of ``/proc/PID/status`` in MB (0 when the process is gone)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0.0
    for line in text.splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def rss_mb(pid: int) -> float:
    """The process's resident memory now (``VmRSS``), MB."""
    return _status_mb(pid, "VmRSS")


def hwm_mb(pid: int) -> float:
    """The process's peak resident memory so far (``VmHWM``), MB."""
    return _status_mb(pid, "VmHWM")


def descendants(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (children of any of its threads, recursively)."""
    out: list[int] = []
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = list(Path(f"/proc/{p}/task").iterdir())
        except OSError:
            continue
        for task in tasks:
            try:
                kids = [int(c) for c in (task / "children").read_text().split()]
            except OSError:
                continue
            out.extend(kids)
            todo.extend(kids)
    return out


class TreePeak:
    """The peak resident memory of process ``pid`` and of its tree while the context is open (sampled
    every ``interval_s``); ``process_mb`` and ``tree_mb`` hold the peaks once it is closed."""

    def __init__(self, pid: int, interval_s: float = 0.05) -> None:
        self.pid = pid
        self.interval_s = interval_s
        self.tree_mb = 0.0
        self.process_mb = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rss-sampler", daemon=True)

    def sample(self) -> None:
        """Read the tree once and keep the larger sum."""
        total = rss_mb(self.pid) + sum(rss_mb(p) for p in descendants(self.pid))
        self.tree_mb = max(self.tree_mb, total)

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self.sample()

    def __enter__(self) -> TreePeak:
        self.sample()
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._stop.set()
        self._thread.join()
        self.sample()
        self.process_mb = hwm_mb(self.pid)
        self.tree_mb = max(self.tree_mb, self.process_mb)
