"""``bench.rss``: the peak resident memory of a process and of its whole tree, read from /proc."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

from bench.rss import TreePeak, descendants, hwm_mb

# a child that starts a grandchild holding 200 MB (touched), waits for stdin, then exits with it
_TREE = """
import subprocess, sys
hold = "import sys; b = b'x' * (200 << 20); print('held', flush=True); sys.stdin.read()"
g = subprocess.Popen([sys.executable, "-c", hold], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
g.stdout.readline()
print("ready", flush=True)
sys.stdin.read()
g.stdin.close()
g.wait()
"""

# a child that holds 200 MB (touched), then forks a grandchild that shares them untouched
_FORKED = """
import os, sys
b = b'x' * (200 << 20)
if os.fork() == 0:
    sys.stdin.read()
    os._exit(0)
print("ready", flush=True)
sys.stdin.read()
os.wait()
"""


@contextmanager
def _sampled(script: str) -> Iterator[tuple[subprocess.Popen[bytes], TreePeak]]:
    """A child running ``script`` with its one grandchild, sampled for 0.1 s once it says ready; the child
    is told to end (its stdin closed) on the way out."""
    proc = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
        with TreePeak(proc.pid, interval_s=0.01) as peak:
            assert len(descendants(proc.pid)) == 1
            time.sleep(0.1)
        yield proc, peak
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait(timeout=30)


def test_the_tree_peak_counts_a_grandchilds_memory_and_the_process_peak_does_not() -> None:
    with _sampled(_TREE) as (proc, peak):
        assert peak.process_mb == hwm_mb(proc.pid) < 100.0  # the child itself holds little
        assert peak.tree_mb >= peak.process_mb + 150.0  # its grandchild's 200 MB are counted
        assert peak.tree_rss_mb >= peak.process_mb + 200.0
    assert descendants(proc.pid) == [] and hwm_mb(proc.pid) == 0.0  # gone: nothing to read


def test_pages_a_forked_child_shares_count_once_in_the_tree_and_twice_in_the_rss_sum() -> None:
    with _sampled(_FORKED) as (_, peak):
        assert peak.process_mb >= 200.0
        assert peak.tree_rss_mb >= 400.0  # both processes' RSS hold the 200 MB
        assert 200.0 <= peak.tree_mb <= peak.process_mb + 30.0  # the shared pages count once
