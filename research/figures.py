"""PNG figures of the reference experiment (matplotlib, headless)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from app.runs import RunResult  # noqa: E402
from research.reference import ExperimentConfig  # noqa: E402
from services.city import City  # noqa: E402

__all__ = [
    "experiment_figures", "kpi_panels", "timeliness_figure", "route_figure", "price_figure", "save_figure"
]  # fmt: skip

_COLORS = {1: "#1f77b4", 2: "#ff7f0e", 3: "#2ca02c"}
_PANELS = (
    ("matching_rate", "matching rate", 1.0),
    ("avg_wait_s", "average wait, request to pickup (min)", 1 / 60),
    ("gamma", "sensing utility Γ", 1.0),
    ("coverage_rate", "grid coverage rate", 1.0),
    ("completion_rate", "POI completion rate", 1.0),
    ("design_kpi", "design KPI (CNY per instrumented veh-h)", 1.0),
)


def _series(table: Sequence[dict[str, Any]], column: str, scenario: int, mode: str) -> dict[int, list[float]]:
    out: dict[int, list[float]] = {}
    for row in table:
        if row["scenario"] == scenario and row["mode"] == mode and row.get(column) is not None:
            out.setdefault(int(row["n1"]), []).append(float(row[column]))
    return dict(sorted(out.items()))


def _band(ax: Any, table: Sequence[dict[str, Any]], column: str, scenario: int, scale: float = 1.0) -> None:
    """One scenario's ``column`` against N1 (runs with active sensing): the mean over seeds, band = min-max."""
    s = _series(table, column, scenario, "active")
    if not s:
        return
    x = np.array(list(s))
    v = [np.array(vals) * scale for vals in s.values()]
    color = _COLORS.get(scenario)
    ax.plot(x, [a.mean() for a in v], "o-", color=color, label=f"scenario {scenario}")
    ax.fill_between(x, [a.min() for a in v], [a.max() for a in v], color=color, alpha=0.15)


def save_figure(fig: Any, path: Path) -> Path:
    """Lay out, write as PNG and close."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def kpi_panels(cfg: ExperimentConfig, table: Sequence[dict[str, Any]], path: Path) -> Path:
    """The paper's Figures C.1-C.3 in one: each KPI against N1, one line per scenario, band = min-max over seeds."""
    fig, axes = plt.subplots(2, 3, figsize=(13, 7.2))
    for ax, (column, label, scale) in zip(axes.ravel(), _PANELS, strict=True):
        for sc in cfg.scenarios:
            _band(ax, table, column, sc, scale)
        ax.set_xlabel("instrumented taxis N1")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(
        f"{cfg.city}: KPIs against the instrumented fleet (N0 = {cfg.n0}, {cfg.seeds} seeds; line = mean, band = min-max)",
        fontsize=11,
    )
    return save_figure(fig, path)


def timeliness_figure(
    cfg: ExperimentConfig, city: City, results: dict[str, RunResult], n1: int, path: Path
) -> Path:
    """Per POI task: delay (completion - scheduled) against scheduled time, with and without active sensing;
    unmonitored tasks drawn as crosses above the top."""
    fig, axes = plt.subplots(1, len(cfg.scenarios), figsize=(4.6 * len(cfg.scenarios), 4.8), squeeze=False)
    for ax, sc in zip(axes[0], cfg.scenarios, strict=True):
        top = 0.0
        marks = []
        for active, color, name in (
            (False, "#d62728", "without active sensing"),
            (True, "#1f77b4", "with active sensing"),
        ):
            xs, ys, miss = [], [], []
            for r in results.values():
                s = r.spec
                if s.scenario != sc or s.n1 != n1 or s.wait_only or s.active != active:
                    continue
                start = city.horizon.start_s(r.date)
                for t in r.kpis.tasks:
                    h = (t.scheduled_at_s - start) / 3600.0
                    if t.delay_s is None:
                        miss.append(h)
                    else:
                        xs.append(h)
                        ys.append(t.delay_s / 60.0)
            if ys:
                top = max(top, max(ys))
            marks.append((xs, ys, miss, color, name))
        for xs, ys, miss, color, name in marks:
            ax.scatter(xs, ys, s=7, alpha=0.45, color=color, label=f"{name}: {len(miss)} unmonitored")
            if miss:
                ax.scatter(miss, np.full(len(miss), top * 1.08 + 1), marker="x", s=14, color=color)
        ax.set_title(f"scenario {sc}, N1 = {n1}", fontsize=10)
        ax.set_xlabel("scheduled time (h after horizon start)")
        ax.set_ylabel("completion - scheduled (min)")
        ax.legend(fontsize=7, loc="upper right")
        ax.grid(alpha=0.3)
    fig.suptitle(
        "POI monitoring timeliness, all seeds pooled (x above the points: never monitored)", fontsize=11
    )
    return save_figure(fig, path)


def route_figure(city: City, result: RunResult, path: Path) -> Path:
    """The run's enhanced A* monitoring routes on the map, over the network and the 1 km grid."""
    net, grid = city.network, city.grid
    fig, ax = plt.subplots(figsize=(8.5, 8))
    x, y = net.x_m / 1000.0, net.y_m / 1000.0
    from matplotlib.collections import LineCollection

    segs = np.stack(
        [np.column_stack([x[net.edge_u], y[net.edge_u]]), np.column_stack([x[net.edge_v], y[net.edge_v]])],
        axis=1,
    )
    ax.add_collection(LineCollection(list(segs), colors="#cccccc", linewidths=0.4))
    x0, y0 = grid.origin_x_m / 1000.0, grid.origin_y_m / 1000.0
    for c in range(grid.n_cols + 1):
        ax.axvline(x0 + c * grid.cell_m / 1000.0, color="#eeeeee", lw=0.6, zorder=0)
    for r in range(grid.n_rows + 1):
        ax.axhline(y0 + r * grid.cell_m / 1000.0, color="#eeeeee", lw=0.6, zorder=0)
    routes = result.routes or ()
    cmap = plt.get_cmap("viridis")
    start = city.horizon.start_s(result.date)
    for rt in routes:
        p = np.asarray(rt.path, dtype=np.int64)
        hour = (rt.time_s - start) / city.horizon.length_s
        ax.plot(x[p], y[p], color=cmap(hour), lw=1.1, alpha=0.8)
        ax.plot(x[p[-1]], y[p[-1]], "o", color=cmap(hour), ms=3)
    done = [t for t in result.kpis.tasks if t.delay_s is not None]
    miss = [t for t in result.kpis.tasks if t.delay_s is None]
    ax.plot(
        x[[t.node for t in done]],
        y[[t.node for t in done]],
        "^",
        color="#2ca02c",
        ms=5,
        label=f"POI monitored ({len(done)})",
        mfc="none",
    )
    if miss:
        ax.plot(
            x[[t.node for t in miss]],
            y[[t.node for t in miss]],
            "^",
            color="#d62728",
            ms=6,
            label=f"POI not monitored ({len(miss)})",
        )
    s = result.spec
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=matplotlib.colors.Normalize(0, city.horizon.length_s / 3600.0))
    fig.colorbar(sm, ax=ax, shrink=0.7, label="dispatch time (h after horizon start)")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel(f"x (km, {net.crs})")
    ax.set_ylabel("y (km)")
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title(
        f"{city.name}: {len(routes)} enhanced A* monitoring routes (scenario {s.scenario}, N1 = {s.n1}, seed {s.seed})",
        fontsize=10,
    )
    return save_figure(fig, path)


def price_figure(cfg: ExperimentConfig, table: Sequence[dict[str, Any]], path: Path) -> Path:
    """Price of sensing against N1: extra average wait and extra riders unserved versus wait-only matching."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for sc in cfg.scenarios:
        _band(axes[0], table, "pos_extra_avg_wait_s", sc)
        _band(axes[1], table, "pos_extra_riders_lost", sc)
    axes[0].set_title("extra average wait vs wait-only matching (s)", fontsize=10)
    axes[1].set_title("extra riders unserved vs wait-only matching", fontsize=10)
    for ax in axes:
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xlabel("instrumented taxis N1")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    return save_figure(fig, path)


def experiment_figures(
    cfg: ExperimentConfig,
    city: City,
    table: Sequence[dict[str, Any]],
    results: dict[str, RunResult],
    out_dir: Path,
) -> dict[str, Path]:
    """Every figure of the report; returns name -> file."""
    out_dir.mkdir(parents=True, exist_ok=True)
    n_max = max(cfg.sizes)
    figs = {"kpis": kpi_panels(cfg, table, out_dir / "kpi_vs_n1.png")}
    if cfg.passive:
        figs["timeliness"] = timeliness_figure(cfg, city, results, n_max, out_dir / "timeliness.png")
    if cfg.baseline:
        figs["price"] = price_figure(cfg, table, out_dir / "price_of_sensing.png")
    routed = [
        r
        for r in results.values()
        if r.routes is not None and r.spec.n1 == n_max and r.spec.scenario == cfg.scenarios[0]
    ]
    if routed:
        figs["routes"] = route_figure(city, min(routed, key=lambda r: r.spec.seed), out_dir / "routes.png")
    return figs
