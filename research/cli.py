"""``python -m research experiment`` (the paper's numerical test) and ``python -m research fleet-experiment``
(fleet sizing on train/test days, the paper's Table 2)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from app.adapters.city_registry import CityRegistry
from app.settings import Settings
from research.experiment import run_experiment
from research.reference import ExperimentConfig
from research.runs import RunFailed

__all__ = ["main", "experiment_main", "fleet_experiment_main"]

ROOT = Path(__file__).resolve().parents[1]  # the repository (research/ lies at its top)


def _numbers(kind: type[int] | type[float], text: str) -> tuple[Any, ...]:
    """A comma-separated list of at least one number (argparse type)."""
    what = "integers" if kind is int else "numbers"
    try:
        values = tuple(kind(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError(f"expected at least one of the {what}")
    return values


def _ints(text: str) -> tuple[int, ...]:
    return _numbers(int, text)


def _floats(text: str) -> tuple[float, ...]:
    return _numbers(float, text)


def _optional_int(text: str) -> int | None:
    """An integer, or ``off`` for none (argparse type)."""
    if text.strip().lower() in ("off", "none"):
        return None
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer or 'off', got {text!r}") from None


def _registry() -> CityRegistry:
    """The cities the service's settings name (``SD_CITIES_DIR``, ``SD_BUNDLED_CITIES_DIR``)."""
    return CityRegistry.from_settings(Settings())


def experiment_main(argv: Sequence[str]) -> int:
    """Run (or resume) the reference experiment and write its report."""
    ap = argparse.ArgumentParser(
        prog="python -m research experiment",
        description="The paper's numerical test: scenarios x N1 x seeds, with and without active sensing, "
        "plus wait-only baselines; resumable; writes CSV, manifest, figures and a markdown report.",
    )
    ap.add_argument("--city", default="chengdu")
    ap.add_argument("--scenarios", type=_ints, default=(1, 2, 3), help="e.g. 1,2,3")
    ap.add_argument(
        "--sizes", type=_ints, default=(10, 20, 30, 40, 50, 60), help="instrumented fleet sizes N1"
    )
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--n0", type=int, default=60, help="ordinary taxis")
    ap.add_argument("--tasks", type=int, default=85, help="POI tasks per run")
    ap.add_argument("--no-passive", action="store_true", help="skip the runs without active sensing")
    ap.add_argument("--no-baseline", action="store_true", help="skip the wait-only runs (price of sensing)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--scheduler", default=None, help="run on the Dask cluster at this address (tcp://...)")
    ap.add_argument("--out", type=Path, default=ROOT / "var" / "experiment", help="run cache (resumable)")
    ap.add_argument("--report-dir", type=Path, default=ROOT / "docs" / "results", help="CSV, figures, report")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(list(argv))
    try:
        cfg = ExperimentConfig(
            city=args.city, scenarios=args.scenarios, sizes=args.sizes, seeds=args.seeds, n0=args.n0,
            n_tasks=args.tasks, passive=not args.no_passive, baseline=not args.no_baseline,
        )  # fmt: skip
    except ValueError as exc:
        ap.error(str(exc))
    try:
        manifest = run_experiment(
            cfg, args.out, args.report_dir, jobs=args.jobs, quiet=args.quiet, registry=_registry(),
            scheduler=args.scheduler,
        )  # fmt: skip
    except RunFailed as exc:
        print(f"experiment: {exc}", file=sys.stderr)
        return 1
    print(
        f"{manifest['runs']} runs; this invocation took {manifest['wall_s_this_invocation']:.1f} s on {args.jobs} "
        f"process(es); report: {args.report_dir / 'EXPERIMENT.md'}"
    )
    return 0


def fleet_experiment_main(argv: Sequence[str]) -> int:
    """Train on some demand days, choose N1 by Deterministic / DRO / DRO_RH, test on held-out days."""
    from research.fleet import DEFAULT_ZETAS, FleetExperimentConfig, run_fleet_experiment
    from services.fleet.sizing import FleetInputError

    ap = argparse.ArgumentParser(
        prog="python -m research fleet-experiment",
        description="The paper's Table 2 on the platform's total cost: simulate every (fleet, scenario, N1, "
        "day), choose N1 on training days for every subsidy, judge the choices by their realized cost on "
        "test days; sensitivity over alpha and the divergence. Resumable.",
    )
    ap.add_argument("--city", default="chengdu")
    ap.add_argument("--scenarios", type=_ints, default=(1, 2, 3))
    ap.add_argument("--sizes", type=_ints, default=(10, 20, 30, 40, 50, 60))
    ap.add_argument("--train-days", type=int, default=10, help="M, demand days 1..M")
    ap.add_argument("--test-days", type=int, default=10, help="held-out days after the training days")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n0", type=int, default=60, help="ordinary taxis beside every N1")
    ap.add_argument(
        "--total-fleet", type=_optional_int, default=120, help="fixed N0 + N1 variant (off: skip it)"
    )
    ap.add_argument("--tasks", type=int, default=85)
    ap.add_argument("--vary-tasks", action="store_true", help="redraw the POI tasks every day")
    ap.add_argument("--divergence", default="kl")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--zetas", type=_floats, default=DEFAULT_ZETAS, help="subsidies, CNY/vehicle-hour")
    ap.add_argument("--keep", type=int, default=7, help="DRO_RH: history days kept after conditioning")
    ap.add_argument(
        "--reach-s", type=float, default=1200.0, help="tasks due this close to the end do not count"
    )
    ap.add_argument("--target", type=float, default=None, help="worst-case completion target (default off)")
    ap.add_argument("--sweep-alphas", type=_floats, default=(0.01, 0.05, 0.1, 0.25))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scheduler", default=None, help="run on the Dask cluster at this address (tcp://...)")
    ap.add_argument("--out", type=Path, default=ROOT / "var" / "experiment", help="run cache (resumable)")
    ap.add_argument("--report-dir", type=Path, default=ROOT / "docs" / "results")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(list(argv))
    try:
        cfg = FleetExperimentConfig(
            city=args.city, scenarios=args.scenarios, sizes=args.sizes, train_days=args.train_days,
            test_days=args.test_days, seed=args.seed, n0=args.n0, total_fleet=args.total_fleet,
            n_tasks=args.tasks, vary_tasks=args.vary_tasks, divergence=args.divergence, alpha=args.alpha,
            zetas=args.zetas, keep=args.keep, reach_s=args.reach_s, completion_target=args.target,
            sweep_alphas=args.sweep_alphas,
        )  # fmt: skip
        manifest = run_fleet_experiment(
            cfg, args.out, args.report_dir, jobs=args.jobs, quiet=args.quiet, registry=_registry(),
            scheduler=args.scheduler,
        )  # fmt: skip
    except (ValueError, FleetInputError) as exc:
        ap.error(str(exc))
    except RunFailed as exc:
        print(f"fleet-experiment: {exc}", file=sys.stderr)
        return 1
    for d in manifest["decisions"]:
        r = d["realized"]
        print(
            f"{d['variant']}, scenario {d['scenario']}, zeta {d['zeta']:g}: Deterministic {d['deterministic']['size']}, "
            f"DRO {d['dro']['size']}, box LP {d['box_lp']['size']}, DRO_RH day-ahead {d['dro_rh_day_ahead']}; "
            f"realized CNY/h: det {r['deterministic']:.2f}, DRO {r['dro']:.2f}, DRO_RH {r['dro_rh']:.2f}"
        )
    print(f"report: {args.report_dir / 'FLEET_SIZING.md'}")
    return 0


_COMMANDS = {"experiment": experiment_main, "fleet-experiment": fleet_experiment_main}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m research COMMAND [options]``; returns the exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] not in _COMMANDS:
        names = ", ".join(_COMMANDS)
        print(f"usage: python -m research {{{names}}} [-h] [options]", file=sys.stderr)
        return 0 if args[:1] in (["-h"], ["--help"]) else 2
    return _COMMANDS[args[0]](args[1:])
