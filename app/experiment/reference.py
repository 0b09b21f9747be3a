"""The paper's numerical test (Section 4): scenarios x instrumented fleet sizes x seeds, with and without
active sensing, plus the wait-only baseline of every run for the price of sensing."""

from __future__ import annotations

import csv
import dataclasses
import datetime as dt
import json
import platform
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.experiment.runner import run_all
from app.experiment.workload import RunSpec, load
from services.sim.demand import DEMAND_VERSION
from services.sim.engine import SIM_VERSION
from services.sim.kpi import price_of_sensing

__all__ = ["ExperimentConfig", "specs", "rows", "run_experiment", "aggregate", "KPI_COLUMNS"]

KPI_COLUMNS = (
    "n_requests", "n_matched", "n_step1", "n_step2", "matching_rate", "avg_wait_s", "avg_pickup_s",
    "total_wait_s", "riders_lost", "riders_unserved", "gamma", "coverage_rate", "n_tasks", "n_completed",
    "n_active", "n_passive", "completion_rate", "mean_delay_s", "route_km", "monitoring_cost_cny",
    "design_kpi", "solve_ms_median",
)  # fmt: skip


@dataclass(frozen=True, slots=True)
class ExperimentConfig:
    """What to run. The defaults are the paper's: 3 scenarios x N1 in 10..60 x 10 seeds, N0 = 60."""

    city: str = "chengdu"
    scenarios: tuple[int, ...] = (1, 2, 3)
    sizes: tuple[int, ...] = (10, 20, 30, 40, 50, 60)
    seeds: int = 10
    n0: int = 60
    n_tasks: int = 85
    passive: bool = True  # also run every setting with active sensing (Step 3) off
    baseline: bool = True  # also run every setting matched on wait alone (price of sensing)

    def __post_init__(self) -> None:
        if not self.scenarios or not self.sizes or self.seeds < 1:
            raise ValueError("need at least one scenario, one size and one seed")
        if any(x < 1 for x in self.sizes) or self.n0 < 0 or self.n_tasks < 0:
            raise ValueError("fleet sizes must be positive, N0 and the task count non-negative")


def specs(cfg: ExperimentConfig) -> list[RunSpec]:
    """Every run of the experiment (runs with active sensing keep their routes for seed 0)."""
    out: list[RunSpec] = []
    for sc in cfg.scenarios:
        for x in cfg.sizes:
            for seed in range(cfg.seeds):
                base = RunSpec(
                    cfg.city, sc, x, cfg.n0, seed, 0, True, False, cfg.n_tasks, keep_routes=seed == 0
                )
                out.append(base)
                if cfg.passive:
                    out.append(dataclasses.replace(base, active=False, keep_routes=False))
                if cfg.baseline:
                    out.append(base.baseline())
    return out


def _mode(spec: dict[str, Any]) -> str:
    return "wait_only" if spec["wait_only"] else ("active" if spec["active"] else "passive")


def rows(results: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per run: the spec, the KPIs and, for sensing runs, the price of sensing against the baseline."""
    by_key = results
    out = []
    for key, r in sorted(results.items()):
        s = r["spec"]
        row: dict[str, Any] = {
            "key": key, "city": s["city"], "scenario": s["scenario"], "n1": s["n1"], "n0": s["n0"],
            "seed": s["seed"], "mode": _mode(s), "demand_seed": r["demand"]["seed"],
            "demand_generator": r["demand"]["generator"], "n_unposted": r["n_unposted"],
        }  # fmt: skip
        row.update({c: r["kpis"].get(c) for c in KPI_COLUMNS})
        base = by_key.get(RunSpec(**{**s, "keep_routes": False}).baseline().key)
        if base is not None and not s["wait_only"]:
            row.update({f"pos_{k}": v for k, v in price_of_sensing(r["kpis"], base["kpis"]).items()})
        out.append(row)
    return out


def aggregate(
    table: Sequence[dict[str, Any]], column: str, mode: str = "active"
) -> dict[tuple[int, int], dict[str, float]]:
    """Mean, sd, min and max of ``column`` over seeds, per (scenario, N1)."""
    groups: dict[tuple[int, int], list[float]] = {}
    for row in table:
        v = row.get(column)
        if row["mode"] != mode or v is None:
            continue
        groups.setdefault((row["scenario"], row["n1"]), []).append(float(v))
    return {
        k: {"mean": float(np.mean(v)), "sd": float(np.std(v, ddof=1)) if len(v) > 1 else 0.0,
            "min": float(np.min(v)), "max": float(np.max(v)), "n": float(len(v))}
        for k, v in groups.items()
    }  # fmt: skip


def _git_commit() -> str | None:
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


def run_experiment(
    cfg: ExperimentConfig, out_dir: Path, report_dir: Path, *, jobs: int = 2, quiet: bool = False
) -> dict[str, Any]:
    """Run (or resume) the experiment, then write the CSV, manifest, figures and report."""
    from app.experiment import figures, report

    started = time.perf_counter()
    all_specs = specs(cfg)
    results = run_all(all_specs, out_dir, jobs=jobs, desc=f"experiment ({cfg.city})", quiet=quiet)
    wall_s = time.perf_counter() - started
    table = rows(results)
    report_dir.mkdir(parents=True, exist_ok=True)
    csv_path = report_dir / "experiment_runs.csv"
    with csv_path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for row in table for k in row)))
        writer.writeheader()
        writer.writerows(table)
    city, _ = load(cfg.city)
    import numpy
    import scipy

    manifest = {
        "experiment": "reference (paper Section 4)",
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "config": dataclasses.asdict(cfg),
        "runs": len(all_specs),
        "wall_s_this_invocation": wall_s,
        "run_s_sum": float(sum(r["elapsed_s"] for r in results.values())),
        "jobs": jobs,
        "versions": {
            "git_commit": _git_commit(), "sim": SIM_VERSION, "demand": DEMAND_VERSION,
            "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__,
        },
        "seeds": {"runs": list(range(cfg.seeds)), "rule": "demand, taxis, tasks and drift all derive from (seed, day)"},
        "city": {"name": city.name, "source": city.source, "params": dataclasses.asdict(city.params),
                 "horizon": {k: str(v) for k, v in dataclasses.asdict(city.horizon).items()}},
        "demand_example": next(iter(results.values()))["demand"],
    }  # fmt: skip
    (report_dir / "experiment_manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    figs = figures.experiment_figures(cfg, table, results, report_dir / "figures")
    report.write_experiment_report(cfg, table, manifest, figs, report_dir / "EXPERIMENT.md")
    return manifest
