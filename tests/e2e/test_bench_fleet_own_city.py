"""The own-city benchmark's smoke run (``python -m bench.bench_fleet_own_city`` on a 10 x 10 grid, 24 taxis,
M = 2): what tests/e2e/test_fleet_own_city.py does not post -- a network with one-way streets, missing links
and scattered node ids, the default 4-hour horizon, busy taxis moving along the paths the service gave them,
riders posted again until matched or expired (each day's requests must be its new riders, counted once),
tasks dispatched on the history days -- and the benchmark itself kept running."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.e2e.service import ROOT

pytestmark = pytest.mark.slow


def test_the_benchmark_sizes_a_small_imported_city_and_its_checks_pass() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "bench.bench_fleet_own_city", "--side", "10", "--taxis", "24", "--days", "2",
         "--no-write", "--solve-timeout-s", "600"],
        cwd=ROOT, capture_output=True, text=True, timeout=1200,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    assert "Checks (all pass)" in done.stdout, done.stdout[-4000:]
    assert "| simulation.n0 (source) | 18 (recorded) |" in done.stdout
    assert "| candidate sizes (source) | [2, 3, 5, 6, 9, 12] (recorded) |" in done.stdout
