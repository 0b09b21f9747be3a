"""The fleet-sizing experiment (paper Table 2): train on some demand days, choose N1 by Deterministic, DRO
(exact and the paper's box LP) and DRO_RH, and judge the choices by their *realized* total cost on held-out
days; for several subsidies ζ, with N0 fixed and with the total fleet fixed; plus a sensitivity sweep.

Every (variant, scenario, N1, day) is one simulated horizon (``RunSpec(day=d)``: day d of the demand
history, its own volume factor and spatial jitter). The POI tasks are one fixed draw for every day
(``tasks_day``), so the uncertainty the DRO prices is demand (docs/METHOD.md section 8); ``vary_tasks``
redraws them per day. Days 1..M train, the next T days test. The report lives in ``research.fleet_report``.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.adapters.city_registry import CityRegistry
from app.runs import RunResult, RunSpec
from app.runs.outcomes import day_outcomes, hourly_volumes
from research.fleet_config import DEFAULT_ZETAS, FleetExperimentConfig, Variant
from research.fleet_report import write_fleet_report
from research.runs import city_of, run_all, versions
from services.city import Horizon
from services.fleet.dro import DIVERGENCES
from services.fleet.evaluation import Realized, realized_by_hour, realized_fixed, rolling_decisions
from services.fleet.sizing import (
    Ambiguity,
    CandidateTable,
    Choice,
    CostModel,
    DayOutcomes,
    FleetPlan,
    choose,
    plan_fleet,
    rolling_hour,
)

__all__ = ["DEFAULT_ZETAS", "FleetExperimentConfig", "Variant", "fleet_specs", "run_fleet_experiment"]


def fleet_specs(cfg: FleetExperimentConfig) -> list[RunSpec]:
    """Every run of the experiment (the variants share the runs where N0 coincides)."""
    specs = {
        cfg.spec(v, sc, x, d).key: cfg.spec(v, sc, x, d)
        for v in cfg.variants
        for sc in cfg.scenarios
        for x in cfg.sizes
        for d in [*cfg.train, *cfg.test]
    }
    return list(specs.values())


@dataclass(frozen=True, slots=True)
class _Data:
    """One (variant, scenario): outcomes and volumes of the training and the test days, and the runs."""

    train: dict[int, DayOutcomes]
    test: dict[int, DayOutcomes]
    train_volumes: np.ndarray
    test_volumes: np.ndarray
    runs_train: dict[int, list[RunResult]]
    runs_test: dict[int, list[RunResult]]


def _data(
    cfg: FleetExperimentConfig, results: Mapping[str, RunResult], hz: Horizon, v: Variant, sc: int
) -> _Data:
    def runs(days: range) -> dict[int, list[RunResult]]:
        return {x: [results[cfg.spec(v, sc, x, d).key] for d in days] for x in cfg.sizes}

    tr, te = runs(cfg.train), runs(cfg.test)
    first = cfg.sizes[0]
    return _Data(
        {x: day_outcomes(r, hz, cfg.reach_s) for x, r in tr.items()},
        {x: day_outcomes(r, hz, cfg.reach_s) for x, r in te.items()},
        hourly_volumes(tr[first]),
        hourly_volumes(te[first]),
        tr,
        te,
    )


def _choice_doc(c: Choice) -> dict[str, Any]:
    return {"size": c.size, "objective": c.objective, "tied": list(c.tied), "status": c.status,
            "target_met": c.target_met}  # fmt: skip


def _table_rows(table: CandidateTable) -> list[dict[str, Any]]:
    out = []
    for r in table.rows:
        out.append({
            "n1": r.size, "mean": r.cost.mean, "worst_case": r.cost.worst_case, "premium": r.cost.premium,
            "box_lp_worst_case": r.box_lp_worst_case, "rho": r.cost.rho, "m": r.cost.m, "status": r.cost.status,
            "design_kpi_mean": r.design_kpi_mean, "design_kpi_worst_case": r.design_kpi_worst_case,
            "completion_mean": None if r.completion is None else r.completion.mean,
            "completion_worst_case": None if r.completion is None else r.completion.worst_case,
        })  # fmt: skip
    return out


def _views(
    cfg: FleetExperimentConfig, d: _Data, amb: Ambiguity, cm: CostModel, day: int
) -> list[list[int | None]]:
    """``views[k][h]``: the size published for hour ``h`` once ``k`` hours of test day ``day`` were observed
    (``None`` for hours already past)."""
    n_hours = d.test_volumes.shape[1]
    obs = d.test_volumes[day]
    return [
        [
            None
            if h < k
            else rolling_hour(
                d.train, d.train_volumes, obs[:k], h, keep=cfg.keep, ambiguity=amb, costs=cm,
                target=cfg.completion_target,
            ).choice.size
            for h in range(n_hours)
        ]
        for k in range(n_hours)
    ]  # fmt: skip


def _evaluate(
    cfg: FleetExperimentConfig, d: _Data, amb: Ambiguity, zeta: float
) -> tuple[FleetPlan, dict[str, Realized], list[list[int]]]:
    cm = CostModel(zeta)
    plan = plan_fleet(d.train, d.train_volumes, amb, cm, keep=cfg.keep, target=cfg.completion_target)
    rh_sizes = [
        [r.choice.size for r in rolling_decisions(
            d.train, d.train_volumes, d.test_volumes[j], keep=cfg.keep, ambiguity=amb, costs=cm,
            target=cfg.completion_target)]
        for j in range(d.test_volumes.shape[0])
    ]  # fmt: skip
    test_means = {x: realized_fixed(d.test, x, cm).value for x in cfg.sizes}
    hindsight = min(cfg.sizes, key=lambda x: (test_means[x], x))
    real = {
        "deterministic": realized_fixed(d.test, plan.deterministic.size, cm),
        "dro": realized_fixed(d.test, plan.dro.size, cm),
        "box_lp": realized_fixed(d.test, plan.box_lp.size, cm),
        "dro_rh": realized_by_hour(d.test, rh_sizes, cm),
        "hindsight": realized_fixed(d.test, hindsight, cm),
    }
    return plan, real, rh_sizes


def _ops(d: _Data, x: int) -> dict[str, float]:
    """Operational KPIs of size ``x`` over the training days (both wait metrics, named)."""
    runs = d.runs_train[x]

    def mean(key: str) -> float:
        return float(np.nanmean([getattr(r.kpis, key) for r in runs]))

    due = d.train[x].tasks_due.sum()
    done = d.train[x].tasks_done.sum()
    return {
        "matching_rate": mean("matching_rate"), "wait_request_to_pickup_s": mean("avg_wait_s"),
        "pickup_travel_s": mean("avg_pickup_s"), "coverage_rate": mean("coverage_rate"),
        "completion_all_tasks": mean("completion_rate"),
        "completion_reachable": float(done / due) if due else float("nan"),
        "step3_cost_cny_per_h": float(d.train[x].cost_cny.mean(axis=0).sum() / d.train[x].n_hours),
    }  # fmt: skip


def run_fleet_experiment(
    cfg: FleetExperimentConfig,
    out_dir: Path,
    report_dir: Path,
    *,
    jobs: int = 2,
    quiet: bool = False,
    registry: CityRegistry | None = None,
    scheduler: str | None = None,
) -> dict[str, Any]:
    """Simulate (or resume) every run, decide, evaluate, and write tables, samples, figure and report."""
    results = run_all(
        fleet_specs(cfg),
        out_dir,
        jobs=jobs,
        desc=f"fleet sizing ({cfg.city})",
        quiet=quiet,
        registry=registry,
        scheduler=scheduler,
    )
    amb = Ambiguity(cfg.divergence, cfg.alpha)
    hz = city_of(cfg.city, registry).horizon
    report_dir.mkdir(parents=True, exist_ok=True)
    (report_dir / "figures").mkdir(exist_ok=True)
    table: list[dict[str, Any]] = []
    decisions: list[dict[str, Any]] = []
    ops: list[dict[str, Any]] = []
    samples: dict[str, Any] = {}
    rolling_example: dict[str, Any] | None = None
    for v in cfg.variants:
        for sc in cfg.scenarios:
            d = _data(cfg, results, hz, v, sc)
            samples[f"{v.name} | scenario {sc}"] = {
                "variant": v.name, "scenario": sc, "train_days": list(cfg.train), "test_days": list(cfg.test),
                "train_volumes": d.train_volumes.tolist(), "test_volumes": d.test_volumes.tolist(),
                "train": {str(x): _outcome_doc(o) for x, o in d.train.items()},
                "test": {str(x): _outcome_doc(o) for x, o in d.test.items()},
            }  # fmt: skip
            for x in cfg.sizes:
                ops.append({"variant": v.name, "scenario": sc, "n1": x, "n0": v.n0_for(x), **_ops(d, x)})
            for zeta in cfg.zetas:
                plan, real, rh_sizes = _evaluate(cfg, d, amb, zeta)
                test_means = {x: realized_fixed(d.test, x, CostModel(zeta)).value for x in cfg.sizes}
                rh_day_ahead = {x: float(np.mean([r.table.row(x).cost.worst_case for r in plan.rolling]))
                                for x in cfg.sizes}  # fmt: skip
                for row in _table_rows(plan.daily):
                    x = row["n1"]
                    table.append({"variant": v.name, "scenario": sc, "zeta": zeta, **row,
                                  "dro_rh_day_ahead_worst_case_mean_over_hours": rh_day_ahead[x],
                                  "test_mean": test_means[x], "test_design_kpi": test_means[x] / x})  # fmt: skip
                design = choose(_design_table(plan.daily), "deterministic")
                decisions.append({
                    "variant": v.name, "scenario": sc, "zeta": zeta,
                    "deterministic": _choice_doc(plan.deterministic), "dro": _choice_doc(plan.dro),
                    "box_lp": _choice_doc(plan.box_lp), "dro_rh_day_ahead": list(plan.rolling_sizes),
                    "dro_rh_test_sizes": rh_sizes, "design_kpi_argmin": design.size,
                    "realized": {m: r.value for m, r in real.items()},
                    "realized_per_day": {m: list(r.per_day) for m, r in real.items()},
                    "hindsight_size": real["hindsight"].sizes[0][0],
                })  # fmt: skip
                if rolling_example is None and v.total is None:
                    rolling_example = _find_change(cfg, d, amb, zeta, sc, v)
    sweep = _sweep(cfg, results, hz)
    manifest = {
        "experiment": "fleet sizing (paper Table 2), total-cost objective",
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "config": dataclasses.asdict(cfg),
        "runs": len(fleet_specs(cfg)),
        "train_days": list(cfg.train), "test_days": list(cfg.test),
        "versions": versions(),
        "decisions": decisions,
        "rolling_example": rolling_example,
    }  # fmt: skip
    (report_dir / "fleet_samples.json").write_text(json.dumps(samples, separators=(",", ":")) + "\n")
    (report_dir / "fleet_manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    write_fleet_report(cfg, table, decisions, ops, sweep, rolling_example, manifest, report_dir)
    return manifest


def _design_table(table: CandidateTable) -> CandidateTable:
    """The same table sized on the per-vehicle design KPI (the paper's Table 2 objective), for contrast."""
    rows = tuple(
        dataclasses.replace(
            r, cost=dataclasses.replace(r.cost, mean=r.design_kpi_mean, worst_case=r.design_kpi_worst_case)
        )
        for r in table.rows
    )
    return dataclasses.replace(table, rows=rows)


def _outcome_doc(o: DayOutcomes) -> dict[str, Any]:
    return {
        "cost_cny": o.cost_cny.tolist(),
        "tasks_due": o.tasks_due.tolist(),
        "tasks_done": o.tasks_done.tolist(),
    }


def _find_change(
    cfg: FleetExperimentConfig, d: _Data, amb: Ambiguity, zeta: float, sc: int, v: Variant
) -> dict[str, Any] | None:
    """The first test day on which the published size of a later hour changed as earlier hours came in."""
    for j in range(d.test_volumes.shape[0]):
        views = _views(cfg, d, amb, CostModel(zeta), j)
        for h in range(1, len(views)):
            published = [views[k][h] for k in range(h + 1)]
            if len({p for p in published if p is not None}) > 1:
                return {
                    "variant": v.name, "scenario": sc, "zeta": zeta, "test_day": cfg.test[j], "hour": h,
                    "published_by_hours_observed": published, "views": views,
                    "day_volumes": d.test_volumes[j].tolist(),
                }  # fmt: skip
    return None


def _sweep(cfg: FleetExperimentConfig, results: Mapping[str, RunResult], hz: Horizon) -> list[dict[str, Any]]:
    """DRO's choice and premium under every divergence and alpha (training days, first variant, ζ = first)."""
    rows = []
    v = cfg.variants[0]
    cm = CostModel(cfg.zetas[0])
    for sc in cfg.scenarios:
        d = _data(cfg, results, hz, v, sc)
        for name in DIVERGENCES:
            for alpha in cfg.sweep_alphas:
                plan = plan_fleet(d.train, d.train_volumes, Ambiguity(name, alpha), cm, keep=cfg.keep)
                rows.append({
                    "scenario": sc, "zeta": cm.subsidy_cny_per_vehicle_hour, "divergence": name, "alpha": alpha,
                    "dro_size": plan.dro.size, "worst_case_at_choice": plan.dro.objective,
                    "rho": plan.daily.row(plan.dro.size).cost.rho,
                    "premium_smallest_fleet": plan.daily.rows[0].cost.premium,
                    "premium_largest_fleet": plan.daily.rows[-1].cost.premium,
                })  # fmt: skip
    return rows
