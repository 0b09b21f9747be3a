"""The experiments' runs: specs become jobs on the deployment's city registry and run through the shared
``app.runs.Runner`` (cache under ``<out>/runs``, resumable), with a progress bar; plus provenance."""

from __future__ import annotations

import platform
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy
import scipy
from tqdm import tqdm

from app.adapters.city_registry import CityRegistry
from app.runs import (
    ExecutorUnavailable,
    Progress,
    RunCache,
    RunJob,
    Runner,
    RunResult,
    RunSpec,
    make_executor,
    open_bundle,
)
from services.city import City
from services.sim.demand import DEMAND_VERSION
from services.sim.engine import SIM_VERSION

__all__ = ["RunFailed", "run_all", "city_of", "git_commit", "versions"]


class RunFailed(RuntimeError):
    """Some runs raised (or none could start); the others are saved and a rerun only redoes the failed
    ones."""


def city_of(name: str, registry: CityRegistry | None = None) -> City:
    """The city as the runs load it."""
    return open_bundle((registry or CityRegistry()).bundle_dir(name)).city


def run_all(
    specs: Sequence[RunSpec],
    out_dir: Path,
    *,
    jobs: int = 2,
    desc: str = "runs",
    quiet: bool = False,
    registry: CityRegistry | None = None,
    scheduler: str | None = None,
) -> dict[str, RunResult]:
    """Run every spec not already in ``out_dir/runs`` on ``jobs`` local processes, or on the Dask cluster
    whose scheduler is at ``scheduler``; return all results by spec key.

    Raises
    ------
    RunFailed
        Naming the runs that raised (the finished ones are cached), or saying why none could start.
    """
    reg = registry or CityRegistry()
    bundles = {name: reg.bundle_dir(name) for name in {s.city for s in specs}}
    by_spec = {s.key: RunJob(s, bundles[s.city]) for s in specs}
    executor = make_executor(jobs, "local" if scheduler is None else "dask", scheduler=scheduler)
    runner = Runner(RunCache(out_dir / "runs"), executor)
    with tqdm(desc=desc, unit="run", disable=quiet, file=sys.stderr, dynamic_ncols=True) as bar:

        def progress(p: Progress) -> None:
            bar.total = p.total
            bar.update(p.done - bar.n)

        try:
            batch = runner.run(list(by_spec.values()), progress)
        except ExecutorUnavailable as exc:
            raise RunFailed(f"no run could start: {exc}") from exc
        finally:
            runner.close()
    if batch.failures:
        shown = "\n".join(f"{k}: {v}" for k, v in sorted(batch.failures.items()))
        raise RunFailed(f"{len(batch.failures)} run(s) failed (rerun to retry only those):\n{shown}")
    return {key: batch.results[job.key] for key, job in by_spec.items()}


def git_commit() -> str | None:
    """The checked-out commit, if this is a git work tree."""
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).parent,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def versions() -> dict[str, Any]:
    """What produced the numbers: commit, simulator, demand generator, Python and the numeric libraries."""
    return {
        "git_commit": git_commit(), "sim": SIM_VERSION, "demand": DEMAND_VERSION,
        "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__,
    }  # fmt: skip
