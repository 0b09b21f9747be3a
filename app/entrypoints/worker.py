"""``python -m app worker``: options on top of the ``SD_WORKER_*`` settings, then the loop (or one solve)."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any, get_args

from pydantic import ValidationError

from app.adapters.city_registry import CityRegistry
from app.bootstrap import build_worker, make_store, worker_cities
from app.settings import DivergenceName, Settings

__all__ = ["main", "parser", "settings_from_args"]

log = logging.getLogger("app.worker")


def _sizes(text: str) -> list[int]:
    try:
        sizes = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not sizes:
        raise argparse.ArgumentTypeError("no sizes given")
    return sizes


def _target(text: str) -> float | None:
    if text.lower() in ("off", "none"):
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a rate in [0, 1] or 'off', got {text!r}") from None


def parser() -> argparse.ArgumentParser:
    """The worker's command line (every option overrides its ``SD_WORKER_*`` setting)."""
    p = argparse.ArgumentParser(
        prog="python -m app worker",
        description="Fleet-sizing worker: re-solves DRO_RH for the coming hour of every city, every hour "
        "(city local time), and solves admin requests (POST /v1/cities/{city}/fleet/solve). Settings come "
        "from SD_* environment variables; SD_STORE=redis shares the results with the API.",
    )
    p.add_argument("--once", action="store_true", help="solve the coming hour now and exit")
    p.add_argument("--city", action="append", default=None, help="a city to size (repeat; default: all)")
    p.add_argument("--sizes", type=_sizes, default=None, help="candidate sizes N1, e.g. 10,20,30,40,50,60")
    p.add_argument("--days", type=int, default=None, help="M, days of demand history (default 10)")
    p.add_argument("--divergence", choices=get_args(DivergenceName), default=None, help="default kl")
    p.add_argument("--alpha", type=float, default=None, help="significance level (default 0.05)")
    p.add_argument("--jobs", type=int, default=None, help="local simulation processes (default 2)")
    p.add_argument(
        "--executor", choices=("local", "dask"), default=None, help="where runs execute (default local)"
    )
    p.add_argument("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://127.0.0.1:8786")
    p.add_argument(
        "--target",
        type=_target,
        default=argparse.SUPPRESS,
        help="worst-case completion rate of reachable POI tasks each choice must meet, or 'off' (default)",
    )
    p.add_argument(
        "--subsidy",
        type=float,
        default=None,
        help="ζ, CNY per instrumented vehicle-hour (default: docs/FLEET.md)",
    )
    p.add_argument("--rolling-days", type=int, default=None, help="DRO_RH: days kept after conditioning (7)")
    p.add_argument("--tasks", type=int, default=None, help="POI tasks per run (default 85)")
    p.add_argument("--n0", type=int, default=None, help="ordinary taxis per run (default 60)")
    p.add_argument("--rate", type=float, default=None, help="synthetic requests per hour (default: city's)")
    p.add_argument("--seed", type=int, default=None, help="seed of the synthetic history (default 0)")
    p.add_argument("--poll", type=float, default=None, help="seconds between queue polls (default 5)")
    return p


_FIELDS = {
    "city": "worker_cities",
    "sizes": "worker_sizes",
    "days": "worker_days",
    "divergence": "worker_divergence",
    "alpha": "worker_alpha",
    "jobs": "worker_jobs",
    "executor": "worker_executor",
    "scheduler": "dask_scheduler",
    "target": "worker_completion_target",
    "subsidy": "worker_subsidy_cny_per_vehicle_hour",
    "rolling_days": "worker_rolling_days",
    "tasks": "worker_tasks",
    "n0": "worker_n0",
    "rate": "worker_rate_per_hour",
    "seed": "worker_seed",
    "poll": "worker_poll_s",
}


def settings_from_args(args: argparse.Namespace) -> Settings:
    """The environment's settings with the given options on top (validated like the environment)."""
    given: dict[str, Any] = {}
    for option, name in _FIELDS.items():
        if hasattr(args, option) and (getattr(args, option) is not None or option == "target"):
            given[name] = getattr(args, option)
    return Settings(**given)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the worker; exit code 0, or 1 when ``--once`` did not publish, 2 for bad options."""
    args = parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    try:
        settings = settings_from_args(args)
    except ValidationError as exc:
        print(f"python -m app worker: invalid settings:\n{exc}", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    registry = CityRegistry.from_settings(settings)
    cities, unknown = worker_cities(settings, registry)
    if unknown:
        print(f"python -m app worker: unknown cities {unknown}; served: {registry.names()}", file=sys.stderr)
        return 2
    kept_days = settings.store.retention_s // 86400
    if kept_days < settings.sizing.days:
        log.warning(
            "recorded demand is kept %d day(s) (SD_RETENTION_S) but a solve needs M = %d days "
            "(SD_WORKER_DAYS): solves will use the seeded synthetic history",
            kept_days,
            settings.sizing.days,
        )
    if settings.store.kind == "memory":
        if not args.once:
            print(
                "python -m app worker: SD_STORE=memory: no API could read this worker's results. On the "
                "memory store `python -m app run` runs the worker inside the service; a separate worker "
                "needs SD_STORE=redis (or use --once to solve once and print the outcome)",
                file=sys.stderr,
            )
            return 2
        log.warning("SD_STORE=memory: this solve's recommendation lives in this process only")

    store = make_store(settings)
    parts = build_worker(settings, store, registry, cities, embedded=False)
    worker = parts.worker
    if settings.runs.executor == "dask":
        log.info("simulation runs go to the Dask scheduler at %s", settings.runs.dask_scheduler)
    if settings.worker.metrics_port is not None and not args.once:
        from prometheus_client import start_http_server

        start_http_server(settings.worker.metrics_port, registry=parts.metrics.registry)
    try:
        if args.once:
            ok = True
            for city in cities:
                outcome = worker.once(city)
                detail = (
                    f"version {outcome.version}" if outcome.status == "published" else outcome.reason or ""
                )
                hour = worker.horizon(city).label(outcome.interval)
                print(f"{city} {hour}: {outcome.status} {detail} ({outcome.wall_s:.1f} s)")
                ok = ok and outcome.status == "published"
            return 0 if ok else 1
        stop = threading.Event()

        def on_signal(signum: int, _frame: object) -> None:
            log.info("signal %d: stopping after the current step", signum)
            stop.set()

        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        parts.serve(stop)
        return 0
    finally:
        parts.runner.close()
        store.close()
