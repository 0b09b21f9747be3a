"""Resident memory of a process and of its whole tree (its children, theirs, ...), read from Linux's /proc.

``TreePeak`` samples a process tree on a thread while a benchmark drives it: the peak of the process itself
is its ``VmHWM`` (the kernel's exact high-water mark); the tree's is the largest sum over the processes alive
at one sample of their proportional set size (``Pss`` of ``/proc/PID/smaps_rollup``: a page shared by n
processes counts 1/n in each, so the sum counts every page the tree holds once), and, beside it, the largest
sum of their ``VmRSS`` (what ``ps`` would add up: a shared library's pages, or a forked child's untouched
ones, count once per process). A spike shorter than the sampling interval can be missed.
"""

from __future__ import annotations

import threading
from pathlib import Path
from types import TracebackType

__all__ = ["TreePeak", "descendants", "rss_mb", "pss_mb", "hwm_mb"]


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


def pss_mb(pid: int) -> float:
    """The process's proportional set size now (``Pss`` of ``smaps_rollup``), MB (0 when it is gone)."""
    try:
        text = Path(f"/proc/{pid}/smaps_rollup").read_text()
    except OSError:
        return 0.0
    for line in text.splitlines():
        if line.startswith("Pss:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


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
    every ``interval_s``; reading a 1 GB process's ``smaps_rollup`` takes about 2 ms of kernel time):
    ``process_mb`` (the process's ``VmHWM``), ``tree_mb`` (the largest sum of ``Pss``) and ``tree_rss_mb``
    (the largest sum of ``VmRSS``) hold the peaks once it is closed."""

    def __init__(self, pid: int, interval_s: float = 0.1) -> None:
        self.pid = pid
        self.interval_s = interval_s
        self.tree_mb = 0.0
        self.tree_rss_mb = 0.0
        self.process_mb = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rss-sampler", daemon=True)

    def sample(self) -> None:
        """Read the tree once and keep the larger sums."""
        pids = [self.pid, *descendants(self.pid)]
        self.tree_rss_mb = max(self.tree_rss_mb, sum(rss_mb(p) for p in pids))
        self.tree_mb = max(self.tree_mb, sum(pss_mb(p) for p in pids))

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
        self.tree_rss_mb = max(self.tree_rss_mb, self.process_mb)
