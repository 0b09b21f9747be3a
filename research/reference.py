"""The paper's numerical test (Section 4): scenarios x instrumented fleet sizes x seeds, with and without
active sensing, plus the wait-only baseline of every run for the price of sensing."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.runs import RunResult, RunSpec
from services.sim.kpi import price_of_sensing

__all__ = ["ExperimentConfig", "specs", "rows", "aggregate", "KPI_COLUMNS"]

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


def _mode(spec: RunSpec) -> str:
    return "wait_only" if spec.wait_only else ("active" if spec.active else "passive")


def _scalars(result: RunResult) -> dict[str, Any]:
    """The run's KPIs as a table has them (a NaN average is an empty cell)."""
    return {
        k: None if isinstance(v, float) and not math.isfinite(v) else v
        for k, v in result.kpis.scalars().items()
    }


def rows(results: dict[str, RunResult]) -> list[dict[str, Any]]:
    """One row per run (by spec key): the spec, the KPIs and, for sensing runs, the price of sensing against
    the baseline."""
    out = []
    for key, r in sorted(results.items()):
        s = r.spec
        row: dict[str, Any] = {
            "key": key, "city": s.city, "scenario": s.scenario, "n1": s.n1, "n0": s.n0,
            "seed": s.seed, "mode": _mode(s), "demand_seed": r.demand["seed"],
            "demand_generator": r.demand["generator"], "n_unposted": r.n_unposted,
        }  # fmt: skip
        kpis = _scalars(r)
        row.update({c: kpis.get(c) for c in KPI_COLUMNS})
        base = results.get(s.baseline().key)
        if base is not None and not s.wait_only:
            row.update({f"pos_{k}": v for k, v in price_of_sensing(kpis, _scalars(base)).items()})
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
