"""The fleet worker's re-solve on local processes and on a Dask cluster, and what an engine costs per run.

    python -m bench.bench_cluster              # small: Chengdu, sizes 10,30,60 x 4 days (12 runs), 2 repeats
    python -m bench.bench_cluster --full       # the worker's default: sizes 10..60 x 10 days (60 runs)
    python -m bench.bench_cluster --report-only docs/perf_cluster.json

Three executors run the same re-solve (``FleetSolver.solve`` of Chengdu's 08:00 hour on the seeded
synthetic history, an empty run cache every time), in alternating order: 2 local processes
(``ProcessExecutor``), a Dask cluster of 1 worker and one of 2 workers (``LocalCluster``: a scheduler and
single-threaded worker processes on loopback ports). Every re-solve must publish the same recommendation.
Each executor is warmed up first (the worker processes open the city bundle). The per-run overhead is the
wall time of runs that do nothing through 2 local processes and through the 2-worker cluster. The load
average is recorded around every measurement (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.adapters import MemoryStore
from app.adapters.city_registry import CityRegistry
from app.runs import Executor, Finished, ProcessExecutor, RunCache, Runner, open_bundle
from app.runs.dask_executor import DaskExecutor
from app.runs.localcluster import LocalCluster
from app.schemas.fleet import render_recommendation
from app.usecases.fleet_history import SizingConfig
from app.usecases.fleet_solve import FleetSolver
from bench.report import ROOT, stamp, write_section

CITY = "chengdu"
SMALL = SizingConfig(sizes=(10, 30, 60), days=4)
FULL = SizingConfig()  # the worker's defaults: sizes 10..60, M = 10 days
WARM = SizingConfig(sizes=(2, 4), days=2, n0=4, n_tasks=3, rate_per_hour=10.0, seed=99)
NOOP_RUNS = 200


def noop(x: int) -> int:
    """A run that does nothing (module level: the workers import it)."""
    return x


def load() -> float:
    return os.getloadavg()[0]


def summary(values: list[float]) -> dict[str, float]:
    a = np.asarray(values)
    return {"n": int(a.size), "median": float(np.median(a)), "min": float(a.min()), "max": float(a.max())}


def resolve(executor: Executor, config: SizingConfig, cache: Path) -> tuple[float, dict[str, Any], int]:
    """One re-solve from an empty cache: wall time, the recommendation without its statistics, runs."""
    store = MemoryStore()
    sizing = FleetSolver(
        store, Runner(RunCache(cache), executor), config, render=render_recommendation, cities=CityRegistry()
    )
    city = sizing.load_city(CITY)
    target = city.horizon.interval_of(city.horizon.start_s("2026-11-23"))
    started = time.perf_counter()
    out = sizing.solve(CITY, target)
    wall = time.perf_counter() - started
    if out.status != "published":
        raise RuntimeError(f"re-solve failed: {out.reason}")
    record = store.current_recommendation(CITY)
    assert record is not None and record.body_json is not None
    body = json.loads(record.body_json)
    runs = int(body.pop("solve")["runs"])
    return wall, body, runs


def per_run_s(executor: Executor) -> float:
    started = time.perf_counter()
    outs = [e for e in executor.map_unordered(noop, list(range(NOOP_RUNS))) if isinstance(e, Finished)]
    wall = time.perf_counter() - started
    assert sorted(int(e.value or 0) for e in outs) == list(range(NOOP_RUNS))
    return wall / NOOP_RUNS


def measure(config: SizingConfig, reps: int, tmp: Path) -> dict[str, Any]:
    open_bundle(CityRegistry().bundle_dir(CITY))  # numba's cache filled before any worker starts
    clusters: dict[str, LocalCluster] = {}
    startup: dict[str, float] = {}
    for n in (1, 2):
        t = time.perf_counter()
        clusters[f"dask{n}"] = LocalCluster(n, tmp / f"cluster{n}").start()
        startup[f"dask{n}"] = time.perf_counter() - t
    executors: dict[str, Executor] = {
        "local": ProcessExecutor(2),
        "dask1": DaskExecutor(clusters["dask1"].address),
        "dask2": DaskExecutor(clusters["dask2"].address),
    }
    try:
        for name, ex in executors.items():  # every worker process opens the bundle before timing
            resolve(ex, WARM, tmp / f"warm-{name}")
        walls: dict[str, list[float]] = {name: [] for name in executors}
        loads: list[float] = []
        bodies = []
        runs = 0
        order = list(executors)
        for rep in range(reps):
            for name in order if rep % 2 == 0 else order[::-1]:
                loads.append(load())
                wall, body, runs = resolve(executors[name], config, tmp / f"{name}-{rep}")
                loads.append(load())
                walls[name].append(wall)
                bodies.append(body)
                print(f"[{rep}] {name}: {wall:.1f} s ({runs} runs), load {loads[-1]:.1f}", flush=True)
        same = all(b == bodies[0] for b in bodies)
        overhead: dict[str, list[float]] = {"local": [], "dask2": []}
        for _ in range(3):
            for name in overhead:
                overhead[name].append(per_run_s(executors[name]))
        loads.append(load())
    finally:
        for ex in executors.values():
            ex.close()
        for c in clusters.values():
            c.stop()
    return {
        "config": {"sizes": list(config.sizes), "days": config.days, "n0": config.n0, "tasks": config.n_tasks},
        "runs": runs, "reps": reps, "wall_s": {k: summary(v) for k, v in walls.items()},
        "same_recommendation": same, "startup_s": startup,
        "noop_per_run_ms": {k: summary([1000 * x for x in v]) for k, v in overhead.items()},
        "load": summary(loads), "cpus": os.cpu_count(),
    }  # fmt: skip


def write(results: dict[str, Any]) -> None:
    w, c = results["wall_s"], results["config"]
    o, ld = results["noop_per_run_ms"], results["load"]
    rows = [("local", "2 local processes"), ("dask1", "Dask, 1 worker"), ("dask2", "Dask, 2 workers")]
    lines = [
        "## Cluster: the re-solve on Dask distributed",
        "",
        stamp("python -m bench.bench_cluster" + (" --full" if results["runs"] >= 60 else "")),
        "",
        f"One re-solve = `FleetSolver.solve` of Chengdu's 08:00 hour on the seeded synthetic history: sizes "
        f"{', '.join(map(str, c['sizes']))} x {c['days']} days = {results['runs']} whole-day runs ({c['n0']} ordinary "
        f"taxis, {c['tasks']} POI tasks), from an empty run cache, {results['reps']} repeats per executor in "
        f"alternating order. Dask clusters: a scheduler and single-threaded worker processes on loopback ports "
        f"(`app.runs.localcluster`). Load average during the runs {ld['min']:.1f}-{ld['max']:.1f} "
        f"(median {ld['median']:.1f}) on {results['cpus']} cores shared with other work.",
        "",
        "| executor | wall per re-solve, median (s) | min-max (s) | vs 2 local processes |",
        "|---|---|---|---|",
    ]
    for key, label in rows:
        ratio = w[key]["median"] / w["local"]["median"]
        lines.append(
            f"| {label} | {w[key]['median']:.1f} | {w[key]['min']:.1f}-{w[key]['max']:.1f} | {ratio:.2f} |"
        )
    same = "identical" if results["same_recommendation"] else "NOT identical"
    s = results["startup_s"]
    lines += [
        "",
        f"Recommendations of every re-solve: **{same}**. Speed-up of 2 Dask workers over 1: "
        f"{w['dask1']['median'] / w['dask2']['median']:.2f}x. Cluster start-up (scheduler and workers joined): "
        f"{s['dask1']:.1f} s with 1 worker, {s['dask2']:.1f} s with 2. The machine's 2 cores were shared with other "
        f"work (load above): a second process there buys less than a second core would, so compare the ratios "
        f"measured in the same run, not the absolute times.",
        "",
        f"**Per-run overhead** ({NOOP_RUNS} runs that do nothing, 3 repeats): 2 local processes "
        f"{o['local']['median']:.2f} ms per run, 2 Dask workers {o['dask2']['median']:.2f} ms "
        f"(min-max {o['dask2']['min']:.2f}-{o['dask2']['max']:.2f}): the engine adds about "
        f"{o['dask2']['median'] - o['local']['median']:.1f} ms to a run that takes seconds.",
        "",
        '**Metropolitan scale** is measured with its own runs: `make bench-fleet-metro`, "Fleet sizing at '
        "metropolitan scale\" below (a simulated metro250k day, a re-solve's runs on a local cluster, the engine "
        "processes a re-solve needs).",
    ]
    write_section("cluster", "\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="the worker's default re-solve (60 runs)")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--report-only", type=Path, metavar="JSON")
    args = ap.parse_args(argv)
    path = ROOT / "docs" / "perf_cluster.json"
    if args.report_only:
        write(json.loads(args.report_only.read_text()))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        results = measure(FULL if args.full else SMALL, args.reps, Path(tmp))
    path.write_text(json.dumps(results, indent=1) + "\n")
    write(results)
    print(json.dumps(results, indent=1))
    return 0 if results["same_recommendation"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
