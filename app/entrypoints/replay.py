"""``python -m app replay``: one simulated horizon against a running service (``--url``), one started
in-process, or the core itself (``--inprocess``), with a progress bar; prints the run's KPIs."""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

from tqdm import tqdm

from app.adapters.city_registry import CityRegistry
from app.runs import RunSpec, demand_for, open_bundle, tasks_for
from app.settings import Settings
from services.city import City
from services.model import Task
from services.sim.demand import DemandSet, demand_on_date
from services.sim.engine import RunTrace, SimConfig, simulate
from services.sim.kpi import RunKpis, run_kpis
from services.sim.local import LocalDispatcher

__all__ = ["replay_main"]


def _print_kpis(k: RunKpis, out: TextIO) -> None:
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
            f"{h.avg_wait_s / 60:.2f} min, coverage {h.coverage_rate:.1%}, "
            f"cost {h.monitoring_cost_cny:.1f} CNY, {h.tasks_completed} POIs",
            file=out,
        )


def replay_main(argv: Sequence[str]) -> int:
    """Simulate one horizon against a running service (``--url``), one started in-process, or the core."""
    ap = argparse.ArgumentParser(
        prog="python -m app replay",
        description="Drive the dispatch service with one simulated horizon (synthetic Chengdu demand, the "
        "real NYC day for Manhattan, or your own CSV) and print the KPIs.",
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
    spec = RunSpec(
        args.city,
        args.scenario,
        args.n1,
        args.n0,
        args.seed,
        args.day,
        not args.no_active,
        False,
        args.tasks,
        args.rate,
    )
    bundle = open_bundle(CityRegistry.from_settings(Settings()).bundle_dir(spec.city))
    city = bundle.city
    if args.demand is not None:
        from services.sim.demand_csv import read_demand_csv

        demand = read_demand_csv(city, args.demand)
    else:
        demand = demand_for(spec, bundle)
    if args.date is not None:
        try:
            dt.date.fromisoformat(args.date)
        except ValueError:
            ap.error(f"--date {args.date!r} is not YYYY-MM-DD")
        demand = demand_on_date(demand, city.horizon, args.date)
    prefix = "" if args.inprocess else f"rp{spec.seed}x{spec.n1}o{spec.n0}s{spec.scenario}d{spec.day}-"
    config = SimConfig(
        n_instrumented=spec.n1, n_ordinary=spec.n0, n_tasks=spec.n_tasks, seed=spec.seed, id_prefix=prefix
    )
    tasks = tasks_for(spec, bundle, demand.date, prefix)
    print(
        f"{city.name}: {len(demand.requests)} requests ({demand.generator} v{demand.version}, "
        f"seed {demand.seed}) on {demand.date}; N1 {spec.n1}, N0 {spec.n0}, {len(tasks)} POI tasks",
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
    args: argparse.Namespace,
    city: City,
    demand: DemandSet,
    tasks: Sequence[Task],
    config: SimConfig,
    tick: Callable[[int, int], None],
) -> RunTrace | None:
    from app.entrypoints.replay_client import HttpDispatcher, ReplayError, service_client

    if args.inprocess:
        c = city
        if args.no_active:
            c = dataclasses.replace(city, params=dataclasses.replace(city.params, active_sensing=False))
        return simulate(c, demand, tasks, config, LocalDispatcher(c), on_epoch=tick)

    with service_client(args.url, args.token, sys.stderr) as client:
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
