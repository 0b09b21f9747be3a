"""Draw one decision epoch on the Chengdu map: grid counts, Step 1/2 trips and Step 3 sensing routes.

    python scripts/plot_epoch.py [--out docs/figures/epoch_chengdu.png] [--seed 3]

Runs 30 seeded epochs (08:00-09:40) through ``services.dispatch.decide`` so the counts are realistic, then
draws the last one. Each Step 3 route is drawn beside the fastest path to the same POI (kappa = 0), so the
detour the enhanced A* takes to collect sensing utility is visible.
"""

from __future__ import annotations

import argparse
import datetime as dt
from pathlib import Path
from zoneinfo import ZoneInfo

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from services.citydata import load_city  # noqa: E402
from services.dispatch import decide  # noqa: E402
from services.model import (  # noqa: E402
    CountsView,
    IntervalKey,
    Rider,
    RiderId,
    Snapshot,
    Task,
    TaskId,
    Taxi,
    TaxiId,
)
from services.network.graph import road_graph  # noqa: E402
from services.network.heaps import workspace  # noqa: E402
from services.network.point_to_point import fastest_path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "epoch_chengdu.png")
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    city = load_city(ROOT / "app" / "data" / "cities" / "chengdu")
    net, grid = city.network, city.grid
    rng = np.random.default_rng(args.seed)
    n = net.n_nodes
    t0 = dt.datetime(2026, 11, 23, 8, 0, tzinfo=ZoneInfo(city.horizon.timezone)).timestamp()
    counts: dict[IntervalKey, np.ndarray] = {}
    visited: dict[TaxiId, set[tuple[IntervalKey, int]]] = {}
    pois = rng.choice(n, 12, replace=False)
    decision = None
    snap = None
    tasks: list[Task] = []
    for e in range(30):
        now = t0 + 200 * e
        riders = tuple(
            Rider(RiderId(f"r{e}-{i}"), int(rng.integers(n)), int(rng.integers(n)), now) for i in range(10)
        )
        taxis = tuple(Taxi(TaxiId(f"i{i}"), int(rng.integers(n)), True, True) for i in range(30)) + tuple(
            Taxi(TaxiId(f"o{i}"), int(rng.integers(n)), False, True) for i in range(30)
        )
        snap = Snapshot(f"e{e}", now, riders, taxis)
        tasks = [Task(TaskId(f"poi{j}"), int(p), now - 1) for j, p in enumerate(pois)] if e == 29 else []
        view = CountsView(dict(counts), {k: frozenset(v) for k, v in visited.items()})
        decision = decide(city, view, snap, tasks)
        if e < 29:
            for v in decision.visits:
                if (v.interval, v.cell) not in visited.setdefault(v.taxi_id, set()):
                    visited[v.taxi_id].add((v.interval, v.cell))
                    counts.setdefault(v.interval, np.zeros(grid.n_cells, dtype=np.int64))[v.cell] += 1
    assert decision is not None and snap is not None
    k0 = city.horizon.interval_of(snap.time_s)
    lam = counts.get(IntervalKey(k0), np.zeros(grid.n_cells, dtype=np.int64))

    fig, ax = plt.subplots(figsize=(9, 8.5), dpi=110)
    x0, y0 = grid.origin_x_m, grid.origin_y_m
    img = np.ma.masked_where(
        city.cell_weight.reshape(grid.n_rows, grid.n_cols) == 0, lam.reshape(grid.n_rows, grid.n_cols)
    )
    mesh = ax.imshow(
        img, origin="lower", cmap="Greens", alpha=0.55, extent=(0, grid.n_cols, 0, grid.n_rows), vmin=0
    )
    fig.colorbar(mesh, ax=ax, fraction=0.035, pad=0.02, label=f"Λ in {city.horizon.label(k0)}")
    xs, ys = (net.x_m - x0) / grid.cell_m, (net.y_m - y0) / grid.cell_m
    segs = np.stack([np.c_[xs[net.edge_u], ys[net.edge_u]], np.c_[xs[net.edge_v], ys[net.edge_v]]], axis=1)
    ax.add_collection(LineCollection(segs, colors="#bbbbbb", linewidths=0.4, zorder=1))

    def draw(path: tuple[int, ...], **kw: object) -> None:
        p = np.array(path)
        ax.plot(xs[p], ys[p], **kw)  # type: ignore[arg-type]

    for m in decision.rider_matches:
        draw(
            m.path,
            color="#1f77b4" if m.step == 1 else "#7f7f7f",
            lw=1.4 if m.step == 1 else 0.9,
            ls="-" if m.step == 1 else "--",
            zorder=3,
        )
    graph = road_graph(city)
    ws = workspace(graph)
    for a in decision.task_assignments:
        fast = fastest_path(graph, ws, a.path[0], a.path[-1])
        fast_nodes = (a.path[0], *net.edge_v[fast].tolist())
        draw(fast_nodes, color="#d62728", lw=1.0, ls=":", zorder=4)
        draw(a.path, color="#d62728", lw=2.0, zorder=5)
        ax.plot(xs[a.path[0]], ys[a.path[0]], "o", color="#d62728", ms=5, zorder=6)
    ax.plot(xs[pois], ys[pois], "*", color="#ff7f0e", ms=11, mec="k", mew=0.5, zorder=7)
    ax.set_xticks(range(grid.n_cols + 1))
    ax.set_yticks(range(grid.n_rows + 1))
    ax.grid(True, color="#666666", lw=0.4, alpha=0.5)
    ax.set_xlim(0, grid.n_cols)
    ax.set_ylim(0, grid.n_rows)
    ax.set_aspect("equal")
    ax.set_xlabel(f"grid column (1 km cells, {grid.crs}, origin {x0:.0f} E {y0:.0f} N)")
    ax.set_ylabel("grid row")
    s = decision.stats
    clock = dt.datetime.fromtimestamp(snap.time_s, ZoneInfo(city.horizon.timezone))
    ax.set_title(
        f"Chengdu, epoch at {clock:%H:%M}: "
        f"{s['step1_matches']} Step 1 (blue), {s['step2_matches']} Step 2 (grey dashed),\n"
        f"{s['step3_assignments']} Step 3 sensing routes (red; dotted: fastest path to the same POI), POIs ★",
        fontsize=10,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
