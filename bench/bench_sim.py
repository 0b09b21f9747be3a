"""Simulator throughput and the wall time of the whole reference experiment.

    python -m bench.bench_sim                  # paper + city scale epochs/s, then the full experiment
    python -m bench.bench_sim --no-experiment  # throughput only
    python -m bench.bench_sim --report-only docs/perf_sim.json

Paper scale: Chengdu, 60 instrumented + 60 ordinary taxis, scenario 1 synthetic demand (~144 requests/h),
85 POI tasks, one 4-hour horizon (72 epochs) per run. City scale: Manhattan, 2,000 taxis of which 600
instrumented, the real NYC requests of 2014-12-21 08:00-12:00 (~620/h after snapping), 300 POI tasks.
Simulated epochs per second = 72 / the run's wall time (decisions included: the simulator calls the core
in-process). The experiment is `python -m research experiment` with its defaults into a fresh directory.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from app.adapters.city_registry import CityRegistry
from app.runs import RunSpec, open_bundle, simulate_spec
from bench.report import ROOT, stamp, write_section

SCALES = {
    "paper": [RunSpec("chengdu", 1, 60, 60, seed, 0, True, False, 85) for seed in range(5)],
    "city": [RunSpec("manhattan", 1, 600, 1400, seed, 0, True, False, 300) for seed in range(2)],
}


def summary(values: list[float]) -> dict[str, float]:
    a = np.asarray(values)
    return {
        "n": int(a.size), "median": float(np.median(a)), "min": float(a.min()), "max": float(a.max()),
        "iqr": float(np.subtract(*np.percentile(a, [75, 25]))),
    }  # fmt: skip


def throughput(scale: str) -> dict[str, object]:
    runs = SCALES[scale]
    bundle = open_bundle(CityRegistry().bundle_dir(runs[0].city))  # city, kernels: loaded before timing
    walls, eps, solve = [], [], []
    for spec in runs:
        started = time.perf_counter()
        _, trace = simulate_spec(spec, bundle)
        wall = time.perf_counter() - started
        walls.append(wall)
        eps.append(len(trace.epochs) / wall)
        solve.append(float(sum(e.solve_ms for e in trace.epochs)) / 1000.0 / wall)
        print(f"[{scale}] {spec.key}: {wall:.1f} s, {len(trace.epochs) / wall:.1f} epochs/s", flush=True)
    return {
        "runs": [r.key for r in runs], "wall_s": summary(walls), "epochs_per_s": summary(eps),
        "solve_share": summary(solve),
    }  # fmt: skip


def experiment_wall(report_dir: Path | None) -> dict[str, object]:
    """Run the default experiment from an empty run cache (its report goes to ``report_dir`` if given)."""
    with tempfile.TemporaryDirectory() as tmp:
        report = report_dir or Path(tmp) / "report"
        started = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "research", "experiment", "--out", f"{tmp}/runs", "--report-dir", str(report)],
            check=True, cwd=ROOT,
        )  # fmt: skip
        wall = time.perf_counter() - started
        manifest = json.loads((report / "experiment_manifest.json").read_text())
    return {
        "wall_s": wall,
        "runs": manifest["runs"],
        "run_s_sum": manifest["run_s_sum"],
        "jobs": manifest["jobs"],
    }


def write(results: dict[str, object]) -> None:
    lines = [
        "## Simulator throughput",
        "",
        stamp("python -m bench.bench_sim"),
        "",
        "One run = one 4-hour horizon of 72 epochs, decisions from the core in-process (`services.sim`), one",
        "process. Paper scale: Chengdu 60+60 taxis, synthetic scenario-1 demand (~144 requests/h), 85 POI tasks;",
        "city scale: Manhattan 2,000 taxis (600 instrumented), the real 2014-12-21 requests (~620/h), 300 POI tasks.",
        "",
        "| scale | runs | epochs/s median | min-max | IQR | wall per run (s) median | share of time in `decide` |",
        "|---|---|---|---|---|---|---|",
    ]
    for scale in ("paper", "city"):
        r = results.get(scale)
        if not isinstance(r, dict):
            continue
        e, w, s = r["epochs_per_s"], r["wall_s"], r["solve_share"]
        lines.append(
            f"| {scale} | {e['n']} | {e['median']:.1f} | {e['min']:.1f}-{e['max']:.1f} | {e['iqr']:.1f} | "
            f"{w['median']:.1f} | {s['median']:.0%} |"
        )
    write_section("sim", "\n".join(lines))
    exp = results.get("experiment")
    if isinstance(exp, dict):
        verdict = "met" if exp["wall_s"] <= 600 else "NOT met"
        write_section(
            "experiment",
            "\n".join([
                "## The whole reference experiment",
                "",
                stamp("python -m bench.bench_sim"),
                "",
                "`python -m research experiment` with its defaults (3 scenarios x N1 10..60 x 10 seeds, each with and without",
                f"active sensing and matched on wait alone: {exp['runs']} runs) into an empty directory, {exp['jobs']} worker",
                f"processes: **{exp['wall_s']:.0f} s wall** ({exp['wall_s'] / 60:.1f} min; target 10 min: {verdict}); the runs",
                f"themselves add up to {exp['run_s_sum']:.0f} s of process time.",
            ]),
        )  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--no-experiment", action="store_true")
    ap.add_argument("--no-city", action="store_true")
    ap.add_argument("--report-only", type=Path, metavar="JSON")
    ap.add_argument(
        "--experiment-report-dir",
        type=Path,
        default=None,
        help="keep the timed experiment's report here (e.g. docs/results) instead of discarding it",
    )
    args = ap.parse_args(argv)
    path = ROOT / "docs" / "perf_sim.json"
    if args.report_only:
        write(json.loads(args.report_only.read_text()))
        return 0
    results: dict[str, object] = {"paper": throughput("paper")}
    if not args.no_city:
        results["city"] = throughput("city")
    if not args.no_experiment:
        print("full experiment ...", flush=True)
        results["experiment"] = experiment_wall(args.experiment_report_dir)
    path.write_text(json.dumps(results, indent=1) + "\n")
    write(results)
    print(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
