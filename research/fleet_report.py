"""The fleet-sizing experiment's outputs: CSV tables, the trade-off figure and ``FLEET_SIZING.md``."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from research.figures import save_figure  # noqa: E402
from research.fleet_config import FleetExperimentConfig  # noqa: E402

__all__ = ["write_fleet_report"]

_METHODS = (("deterministic", "Deterministic"), ("dro", "DRO"), ("box_lp", "DRO, box LP (Eq. 28)"),
            ("dro_rh", "DRO_RH"))  # fmt: skip


def _csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _f(v: float | None, digits: int = 2) -> str:
    return "" if v is None else f"{v:.{digits}f}"


def _tradeoff_figure(
    cfg: FleetExperimentConfig,
    table: Sequence[dict[str, Any]],
    decisions: Sequence[dict[str, Any]],
    path: Path,
) -> Path:
    variant = cfg.variants[0].name
    fig, axes = plt.subplots(1, len(cfg.scenarios), figsize=(4.8 * len(cfg.scenarios), 4.0), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, sc in zip(axes[0], cfg.scenarios, strict=True):
        for i, zeta in enumerate(cfg.zetas):
            rows = [r for r in table if r["variant"] == variant and r["scenario"] == sc and r["zeta"] == zeta]
            xs = [r["n1"] for r in rows]
            c = colors[i % len(colors)]
            ax.plot(xs, [r["mean"] for r in rows], "--", color=c, alpha=0.7)
            ax.plot(xs, [r["worst_case"] for r in rows], "-", color=c, label=f"ζ = {zeta:g}")
            dec = next(
                d for d in decisions if d["variant"] == variant and d["scenario"] == sc and d["zeta"] == zeta
            )
            x = dec["dro"]["size"]
            ax.plot([x], [dec["dro"]["objective"]], "o", color=c, markersize=8)
        ax.set_title(f"scenario {sc}: total cost per hour (solid: worst case, dashed: mean)", fontsize=9)
        ax.set_xlabel("instrumented taxis N1")
        ax.set_ylabel("CNY per hour")
        ax.legend(fontsize=8, title="dot: DRO's choice", title_fontsize=8)
    return save_figure(fig, path)


def _decision_lines(cfg: FleetExperimentConfig, decisions: Sequence[dict[str, Any]]) -> list[str]:
    lines = [
        "| fleet | scenario | ζ | Deterministic | DRO | box LP | DRO_RH day-ahead (per hour) | DRO_RH on test days "
        "(sizes used) | design-KPI argmin | best fixed size in hindsight |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for d in decisions:
        used = sorted({x for day in d["dro_rh_test_sizes"] for x in day})
        lines.append(
            f"| {d['variant']} | {d['scenario']} | {d['zeta']:g} | {d['deterministic']['size']} | {d['dro']['size']} | "
            f"{d['box_lp']['size']} | {' / '.join(map(str, d['dro_rh_day_ahead']))} | {', '.join(map(str, used))} | "
            f"{d['design_kpi_argmin']} | {d['hindsight_size']} |"
        )
    lines += [
        "",
        "Realized total cost per hour on the held-out test days (CNY/h, mean over days; DRO_RH hour by hour):",
        "",
        "| fleet | scenario | ζ | Deterministic | DRO | box LP | DRO_RH | best fixed in hindsight |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for d in decisions:
        r = d["realized"]
        lines.append(
            f"| {d['variant']} | {d['scenario']} | {d['zeta']:g} | {r['deterministic']:.2f} | {r['dro']:.2f} | "
            f"{r['box_lp']:.2f} | {r['dro_rh']:.2f} | {r['hindsight']:.2f} |"
        )
    return lines


def _table2(
    cfg: FleetExperimentConfig, table: Sequence[dict[str, Any]], decisions: Sequence[dict[str, Any]],
    variant: str, zeta: float, *, design: bool,
) -> list[str]:  # fmt: skip
    sizes = list(cfg.sizes)
    unit = "CNY/h/vehicle" if design else "CNY/h"
    head = (
        "| scenario | method | "
        + " | ".join(str(x) for x in sizes)
        + f" | optimal size | realized at it ({unit}) |"
    )
    lines = [head, "|---|---|" + "---|" * (len(sizes) + 2)]
    for sc in cfg.scenarios:
        rows = {
            r["n1"]: r for r in table if r["variant"] == variant and r["scenario"] == sc and r["zeta"] == zeta
        }
        dec = next(
            d for d in decisions if d["variant"] == variant and d["scenario"] == sc and d["zeta"] == zeta
        )

        def per(x: int, key: str, rows: dict[int, dict[str, Any]] = rows) -> float:
            v = float(rows[x][key])
            return v / x if design and key != "test_design_kpi" else v

        entries = [
            ("Deterministic (mean)", "mean", "deterministic"),
            ("DRO (worst case, exact)", "worst_case", "dro"),
            ("DRO (worst case, box LP)", "box_lp_worst_case", "box_lp"),
            ("DRO_RH (day-ahead, mean of hourly worst cases; a bound, not comparable)",
             "dro_rh_day_ahead_worst_case_mean_over_hours", "dro_rh"),
        ]  # fmt: skip
        for label, key, method in entries:
            if design:
                best = min(sizes, key=lambda x, k=key: (per(x, k), x))  # type: ignore[misc]
                real = float(rows[best]["test_design_kpi"])
                size = str(best)
            elif method == "dro_rh":
                size = "per hour"
                real = dec["realized"]["dro_rh"]
            else:
                size = str(dec[method]["size"])
                real = dec["realized"][method]
            cells = " | ".join(_f(per(x, key)) for x in sizes)
            lines.append(f"| {sc} | {label} | {cells} | {size} | {real:.2f} |")
        key = "test_design_kpi" if design else "test_mean"
        cells = " | ".join(_f(float(rows[x][key])) for x in sizes)
        lines.append(
            f"| {sc} | test days (realized mean) | {cells} | {dec['hindsight_size']} (hindsight) | |"
        )
    return lines


def _ops_lines(cfg: FleetExperimentConfig, ops: Sequence[dict[str, Any]]) -> list[str]:
    lines = [
        "| fleet | scenario | N1 | N0 | matching rate | wait, request to pickup (s) | pickup travel time (s) | "
        "coverage | completion, all tasks | completion, reachable tasks | Step 3 cost (CNY/h) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in ops:
        lines.append(
            f"| {r['variant']} | {r['scenario']} | {r['n1']} | {r['n0']} | {r['matching_rate']:.3f} | "
            f"{r['wait_request_to_pickup_s']:.0f} | {r['pickup_travel_s']:.0f} | {r['coverage_rate']:.3f} | "
            f"{r['completion_all_tasks']:.3f} | {r['completion_reachable']:.3f} | {r['step3_cost_cny_per_h']:.1f} |"
        )
    return lines


def _rolling_lines(example: dict[str, Any] | None, cfg: FleetExperimentConfig) -> list[str]:
    if example is None:
        return ["No test day changed a later hour's published size in this run."]
    h = example["hour"]
    pub = example["published_by_hours_observed"]
    lines = [
        f"{example['variant']}, scenario {example['scenario']}, ζ = {example['zeta']:g}, test day "
        f"{example['test_day']} (requests per hour {', '.join(str(int(v)) for v in example['day_volumes'])}): "
        f"the size published for hour {h} (0-based) was "
        + ", then ".join(f"{x} with {k} hour(s) observed" for k, x in enumerate(pub))
        + ".",
        "",
        "| hours observed | " + " | ".join(f"hour {i}" for i in range(len(example["views"]))) + " |",
        "|---|" + "---|" * len(example["views"]),
    ]
    for k, row in enumerate(example["views"]):
        lines.append(f"| {k} | " + " | ".join("(past)" if x is None else str(x) for x in row) + " |")
    return lines


def write_fleet_report(
    cfg: FleetExperimentConfig,
    table: Sequence[dict[str, Any]],
    decisions: Sequence[dict[str, Any]],
    ops: Sequence[dict[str, Any]],
    sweep: Sequence[dict[str, Any]],
    rolling_example: dict[str, Any] | None,
    manifest: dict[str, Any],
    report_dir: Path,
) -> Path:
    """Write ``fleet_table.csv``, ``fleet_ops.csv``, ``fleet_sensitivity.csv``, the figure and the report."""
    _csv(report_dir / "fleet_table.csv", table)
    _csv(report_dir / "fleet_ops.csv", ops)
    _csv(report_dir / "fleet_sensitivity.csv", sweep)
    fig = _tradeoff_figure(cfg, table, decisions, report_dir / "figures" / "fleet_tradeoff.png")
    path = report_dir / "FLEET_SIZING.md"
    main = cfg.variants[0].name
    lines = [
        "# Fleet sizing: Deterministic, DRO and DRO_RH on the platform's total cost (paper Table 2)",
        "",
        f"Generated by `python -m research fleet-experiment` on {manifest['created']} "
        f"(git {manifest['versions']['git_commit']}).",
        f"City {cfg.city}, N1 in {list(cfg.sizes)}; fleets: {', '.join(v.name for v in cfg.variants)}; "
        f"{cfg.n_tasks} POI tasks, {'redrawn every day' if cfg.vary_tasks else 'one fixed set for every day'}; "
        f"training days {cfg.train.start}-{cfg.train.stop - 1} (M = {cfg.train_days}), held-out test days "
        f"{cfg.test.start}-{cfg.test.stop - 1}; synthetic demand days (volume factor and spatial jitter per day, "
        f"`docs/DEMAND.md`). Ambiguity set: {cfg.divergence}, α = {cfg.alpha}, 10 bins over the data range. "
        f"DRO_RH keeps the {cfg.keep} training days closest to the day's observed hourly volumes. Completion counts "
        f"tasks scheduled at least {cfg.reach_s / 60:.0f} min before the horizon ends"
        + ("" if cfg.completion_target is None else f"; completion target {cfg.completion_target}")
        + ".",
        "",
        "**Objective** (docs/METHOD.md section 7): the platform's total cost per hour, 1.5 CNY/km × Step 3 km "
        "per hour + ζ × N1, ζ in CNY per instrumented vehicle-hour. The per-vehicle design KPI (the paper's "
        "Table 2 column) is that divided by N1. Raw data: `fleet_table.csv` (per size), `fleet_ops.csv`, "
        "`fleet_sensitivity.csv`, `fleet_manifest.json` (decisions, realized costs), `fleet_samples.json` (every "
        "training and test day's Step 3 cost per hour, tasks due and done, hourly volumes: the samples the "
        "decisions used).",
        "",
        "## Decisions and what they cost on the test days",
        "",
        *_decision_lines(cfg, decisions),
        "",
        f"![trade-off]({fig.relative_to(report_dir)})",
        "",
        "## DRO_RH rolls: a later hour's recommendation as the day unfolds",
        "",
        *_rolling_lines(rolling_example, cfg),
        "",
    ]
    for zeta in cfg.zetas:
        lines += [f"## Table 2, total cost per hour (CNY/h), {main}, ζ = {zeta:g}", "",
                  *_table2(cfg, table, decisions, main, zeta, design=False), ""]  # fmt: skip
    lines += [f"## Table 2, the paper's objective: design KPI (CNY/h/vehicle), {main}, ζ = {cfg.zetas[0]:g}", "",
              "Sized on this KPI every method picks the largest candidate: the divisor N1 decides.", "",
              *_table2(cfg, table, decisions, main, cfg.zetas[0], design=True), ""]  # fmt: skip
    if len(cfg.variants) > 1:
        other = cfg.variants[1].name
        lines += [f"## Table 2, total cost per hour (CNY/h), {other}, ζ = {cfg.zetas[0]:g}", "",
                  *_table2(cfg, table, decisions, other, cfg.zetas[0], design=False), ""]  # fmt: skip
    lines += ["## Operations per fleet size (training days, mean)", "",
              "Two wait metrics: request to pickup (waiting to be matched plus the pickup drive) and the pickup "
              "travel time alone (the paper's).", "", *_ops_lines(cfg, ops), ""]  # fmt: skip
    lines += [
        f"## Sensitivity: divergence and α (DRO, {main}, ζ = {cfg.zetas[0]:g}, training days)",
        "",
        "| scenario | divergence | α | ρ | DRO's N1 | worst case at it (CNY/h) | premium at the smallest / largest fleet |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sweep:
        lines.append(
            f"| {r['scenario']} | {r['divergence']} | {r['alpha']} | {r['rho']:.3f} | {r['dro_size']} | "
            f"{r['worst_case_at_choice']:.2f} | {r['premium_smallest_fleet']:.2f} / {r['premium_largest_fleet']:.2f} |"
        )
    lines.append("")
    notes = report_dir / "FLEET_SIZING_NOTES.md"
    if notes.exists():
        lines += [notes.read_text().rstrip(), ""]
    path.write_text("\n".join(lines))
    return path
