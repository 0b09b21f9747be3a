"""``python -m app experiment`` (the paper's numerical test) and ``python -m app replay`` (one run, against
a running service or in-process)."""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx
from tqdm import tqdm

from app.experiment.reference import ExperimentConfig, run_experiment
from app.experiment.runner import RunFailed
from app.experiment.workload import RunSpec, demand_for, load, tasks_for
from services.sim.demand import DemandSet, Request
from services.sim.engine import RunTrace, SimConfig, simulate
from services.sim.kpi import RunKpis, run_kpis
from services.sim.local import LocalDispatcher

__all__ = ["experiment_main", "fleet_experiment_main", "replay_main"]

ROOT = Path(__file__).resolve().parents[2]


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


def experiment_main(argv: Sequence[str]) -> int:
    """Run (or resume) the reference experiment and write its report."""
    ap = argparse.ArgumentParser(
        prog="python -m app experiment",
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
        manifest = run_experiment(cfg, args.out, args.report_dir, jobs=args.jobs, quiet=args.quiet)
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
    from app.experiment.fleet import FleetExperimentConfig, run_fleet_experiment
    from services.fleet import FleetInputError

    ap = argparse.ArgumentParser(
        prog="python -m app fleet-experiment",
        description="The paper's Table 2: simulate every (scenario, N1, day), choose the fleet on training "
        "days, evaluate on test days; sensitivity over alpha and the divergence. Resumable.",
    )
    ap.add_argument("--city", default="chengdu")
    ap.add_argument("--scenarios", type=_ints, default=(1, 2, 3))
    ap.add_argument("--sizes", type=_ints, default=(10, 20, 30, 40, 50, 60))
    ap.add_argument("--train-days", type=int, default=10, help="M, demand days 1..M")
    ap.add_argument("--test-days", type=int, default=5, help="held-out days after the training days")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n0", type=int, default=60)
    ap.add_argument("--tasks", type=int, default=85)
    ap.add_argument("--divergence", default="kl")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--target", type=float, default=0.95, help="worst-case POI completion target")
    ap.add_argument("--sweep-alphas", type=_floats, default=(0.01, 0.05, 0.1, 0.25))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "var" / "experiment", help="run cache (resumable)")
    ap.add_argument("--report-dir", type=Path, default=ROOT / "docs" / "results")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(list(argv))
    try:
        cfg = FleetExperimentConfig(
            city=args.city, scenarios=args.scenarios, sizes=args.sizes, train_days=args.train_days,
            test_days=args.test_days, seed=args.seed, n0=args.n0, n_tasks=args.tasks, divergence=args.divergence,
            alpha=args.alpha, completion_target=args.target, sweep_alphas=args.sweep_alphas,
        )  # fmt: skip
        manifest = run_fleet_experiment(cfg, args.out, args.report_dir, jobs=args.jobs, quiet=args.quiet)
    except (ValueError, FleetInputError) as exc:
        ap.error(str(exc))
    except RunFailed as exc:
        print(f"fleet-experiment: {exc}", file=sys.stderr)
        return 1
    for sc, s in manifest["summary"].items():
        print(
            f"scenario {sc}: Deterministic N1={s['deterministic']['size']} (test {s['deterministic']['test_kpi']:.3f}), "
            f"DRO N1={s['dro']['size']} (test {s['dro']['test_kpi']:.3f}), DRO_RH N1={s['dro_rh']['sizes_by_hour']} "
            f"(test {s['dro_rh']['test_kpi']:.3f}) CNY per instrumented vehicle-hour"
        )
    print(f"report: {args.report_dir / 'FLEET_SIZING.md'}")
    return 0


def _on_date(demand: DemandSet, date: str, start_s: float, new_start_s: float) -> DemandSet:
    shift = new_start_s - start_s
    reqs = tuple(Request(r.id, r.time_s + shift, r.origin, r.destination) for r in demand.requests)
    return dataclasses.replace(demand, date=date, requests=reqs)


def _print_kpis(k: RunKpis, out: Any) -> None:
    print(
        f"requests {k.n_requests}: matched {k.n_matched} ({k.matching_rate:.1%}; step 1 {k.n_step1}, step 2 "
        f"{k.n_step2}), unserved {k.riders_unserved} (left after patience {k.riders_lost}); average wait "
        f"{k.avg_wait_s / 60:.2f} min (pickup drive {k.avg_pickup_s / 60:.2f} min)",
        file=out,
    )
    print(
        f"sensing: Gamma {k.gamma:.4f}, coverage {k.coverage_rate:.1%}; POIs {k.n_completed}/{k.n_tasks} "
        f"monitored ({k.n_active} active, {k.n_passive} passive), mean delay {k.mean_delay_s / 60:.1f} min; "
        f"monitoring cost {k.monitoring_cost_cny:.1f} CNY over {k.route_km:.1f} km, design KPI "
        f"{k.design_kpi:.3f} CNY per instrumented vehicle-hour",
        file=out,
    )
    for h in k.hours:
        print(
            f"  hour {h.interval}: {h.requests} requests, matched {h.matching_rate:.1%}, wait "
            f"{h.avg_wait_s / 60:.2f} min, coverage {h.coverage_rate:.1%}, cost {h.monitoring_cost_cny:.1f} CNY, "
            f"{h.tasks_completed} POIs",
            file=out,
        )


def replay_main(argv: Sequence[str]) -> int:
    """Simulate one horizon against a running service (``--url``), one started in-process, or the core."""
    ap = argparse.ArgumentParser(
        prog="python -m app replay",
        description="Drive the dispatch service with one simulated horizon (synthetic Chengdu demand, the real "
        "NYC day for Manhattan, or your own CSV) and print the KPIs.",
    )
    ap.add_argument("--url", default=None, help="a running service (default: start one in this process)")
    ap.add_argument("--token", default=None, help="bearer token for --url (scopes read and dispatch)")
    ap.add_argument("--inprocess", action="store_true", help="call the core directly, no HTTP")
    ap.add_argument("--city", default="chengdu")
    ap.add_argument("--scenario", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--day", type=int, default=0, help="demand day (0 = base; >0 = another day of the history)"
    )
    ap.add_argument("--n1", type=int, default=60, help="instrumented taxis")
    ap.add_argument("--n0", type=int, default=60, help="ordinary taxis")
    ap.add_argument("--tasks", type=int, default=85)
    ap.add_argument("--rate", type=float, default=None, help="requests per hour (default: the city's)")
    ap.add_argument("--demand", type=Path, default=None, help="a demand CSV instead of the generator")
    ap.add_argument("--date", default=None, help="replay on this local date (YYYY-MM-DD) instead")
    ap.add_argument("--no-active", action="store_true", help="Step 3 off (in-process only)")
    args = ap.parse_args(list(argv))
    if args.no_active and not args.inprocess:
        ap.error("--no-active needs --inprocess (a service decides with its own city's parameters)")
    if args.url and not args.token:
        ap.error("--token is required with --url")
    spec = RunSpec(args.city, args.scenario, args.n1, args.n0, args.seed, args.day, not args.no_active,
                   False, args.tasks, args.rate)  # fmt: skip
    city, _ = load(spec.city)
    if args.demand is not None:
        from services.sim.demand_csv import read_demand_csv

        demand = read_demand_csv(city, args.demand)
    else:
        demand = demand_for(spec)
    if args.date is not None:
        try:
            dt.date.fromisoformat(args.date)
        except ValueError:
            ap.error(f"--date {args.date!r} is not YYYY-MM-DD")
        demand = _on_date(
            demand, args.date, city.horizon.start_s(demand.date), city.horizon.start_s(args.date)
        )
    prefix = "" if args.inprocess else f"rp{spec.seed}x{spec.n1}o{spec.n0}s{spec.scenario}d{spec.day}-"
    config = SimConfig(n_instrumented=spec.n1, n_ordinary=spec.n0, n_tasks=spec.n_tasks, seed=spec.seed,
                       id_prefix=prefix)  # fmt: skip
    tasks = tasks_for(spec, demand.date, prefix)
    print(
        f"{city.name}: {len(demand.requests)} requests ({demand.generator} v{demand.version}, seed {demand.seed}) "
        f"on {demand.date}; N1 {spec.n1}, N0 {spec.n0}, {len(tasks)} POI tasks",
        flush=True,
    )
    n_epochs = city.horizon.length_s // city.horizon.epoch_s
    with tqdm(total=n_epochs, desc="epochs", unit="epoch", file=sys.stderr) as bar:

        def tick(done: int, total: int) -> None:
            bar.update(done - bar.n)

        trace = _replay(args, city, demand, tasks, config, tick)
    if trace is None:
        return 1
    _print_kpis(run_kpis(city, trace), sys.stdout)
    return 0


def _replay(
    args: argparse.Namespace, city: Any, demand: DemandSet, tasks: Any, config: SimConfig, tick: Any
) -> RunTrace | None:
    from app.replay import HttpDispatcher, ReplayError
    from app.serve import serve_in_thread

    if args.inprocess:
        c = city
        if args.no_active:
            c = dataclasses.replace(city, params=dataclasses.replace(city.params, active_sensing=False))
        return simulate(c, demand, tasks, config, LocalDispatcher(c), on_epoch=tick)

    def drive(url: str, token: str) -> RunTrace | None:
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=300) as client:
            try:
                return simulate(
                    city, demand, tasks, config, HttpDispatcher(client, args.city, city), on_epoch=tick
                )
            except ReplayError as exc:
                hint = ""
                if exc.status_code == 409:
                    hint = " (the service holds later or different epochs of this city: pass another --date)"
                print(f"\nreplay: {exc}{hint}", file=sys.stderr)
                return None

    if args.url:
        return drive(args.url.rstrip("/"), args.token)
    with serve_in_thread() as (url, token):
        print(f"started the service in-process at {url} (memory store)", file=sys.stderr)
        return drive(url, token)
