"""Command line: ``python -m app COMMAND`` (run, demo, replay, experiment, fleet-experiment, openapi, ...)."""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import json
import logging
import secrets
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO
from zoneinfo import ZoneInfo

import httpx
import numpy as np

from app.serve import serve_in_thread
from app.settings import Settings

__all__ = [
    "main",
    "new_token",
    "dev_settings",
    "openapi_document",
    "write_openapi",
    "OPENAPI_PATH",
    "DemoConfig",
    "run_demo",
]

OPENAPI_PATH = Path(__file__).resolve().parent.parent / "openapi" / "openapi.json"
_LOOPBACK = {"127.0.0.1", "localhost", "::1"}


def new_token() -> str:
    """A fresh random bearer token."""
    return secrets.token_urlsafe(32)


def dev_settings(settings: Settings) -> tuple[Settings, str | None]:
    """With no configured tokens: add a random token with every scope and bind loopback only."""
    if settings.tokens:
        return settings, None
    token = new_token()
    return settings.model_copy(
        update={"tokens": {token: ["read", "dispatch", "admin"]}, "host": "127.0.0.1"}
    ), token


def openapi_document() -> str:
    """The OpenAPI document of the app, as committed in ``openapi/openapi.json``."""
    from app.adapters.memory_store import MemoryStore
    from app.main import create_app

    app = create_app(Settings(tokens={}, store="memory"), store=MemoryStore())
    return json.dumps(app.openapi(), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def write_openapi(path: Path = OPENAPI_PATH) -> Path:
    """Write the OpenAPI document to ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(openapi_document(), encoding="utf-8")
    return path


# ------------------------------------------------------------------------------------------------ demo


@dataclass(frozen=True, slots=True)
class DemoConfig:
    """What ``python -m app demo`` simulates."""

    city: str = "chengdu"
    epochs: int = 5
    riders: int = 12
    taxis: int = 30
    instrumented_share: float = 0.5
    tasks: int = 4
    seed: int = 7
    date: str = "2026-11-23"


def run_demo(
    config: DemoConfig, url: str | None = None, token: str | None = None, out: TextIO | None = None
) -> int:
    """Register a few tasks and post ``config.epochs`` random epochs; print what was decided."""
    stream = out or sys.stdout
    if url is None:
        with serve_in_thread() as (local_url, local_token):
            print(f"started the service in-process at {local_url} (memory store)", file=stream)
            return _drive(config, local_url, local_token, stream)
    if not token:
        print("demo: --token is required with --url", file=sys.stderr)
        return 2
    return _drive(config, url.rstrip("/"), token, stream)


def _fail(r: httpx.Response, what: str) -> int:
    try:
        err = r.json()
        text = f"{err.get('error')}: {err.get('detail')}"
    except ValueError:
        text = r.text[:300]
    print(f"demo: {what} failed with HTTP {r.status_code} ({text})", file=sys.stderr)
    return 1


def _print_epoch(out: TextIO, head: str, res: dict[str, Any], prefix: str) -> None:
    """A readable summary of one epoch's decision."""

    def short(name: object) -> str:
        return str(name).removeprefix(prefix + "-")

    print(f"\n{head}", file=out)
    for step, label in ((1, "instrumented taxis -> riders"), (2, "regular taxis -> riders")):
        ms = [m for m in res["rider_matches"] if m["step"] == step]
        wait = f"mean wait {np.mean([m['wait_s'] for m in ms]):4.0f} s" if ms else ""
        gain = f"  sensing gain {sum(m['sensing_gain'] for m in ms):.4f}" if step == 1 and ms else ""
        print(f"  step {step}  {label:30s} {len(ms):3d} matches  {wait}{gain}", file=out)
    routes = ", ".join(
        f"{short(a['taxi_id'])} -> {short(a['task_id'])} ({a['length_m'] / 1000:.1f} km, "
        f"{a['travel_time_s'] / 60:.1f} min, {a['cost_cny']:.2f} CNY)"
        for a in res["task_assignments"]
    )
    print(f"  step 3  {'POI monitoring routes':30s} {len(res['task_assignments']):3d}  {routes}", file=out)
    if res["tasks_completed"]:
        done = ", ".join(
            f"{short(t['id'])} ({t['mode']}, {short(t['taxi_id'])})" for t in res["tasks_completed"]
        )
        print(f"  tasks completed: {done}", file=out)
    st = res["stats"]
    print(
        f"  unmatched {len(res['unmatched_rider_ids'])}, expired {len(res['expired_rider_ids'])}"
        f" | Gamma {st.get('gamma', 0.0):.5f} (+{st.get('gamma_gain', 0.0):.5f})"
        f" | solved in {st.get('solve_ms', 0.0):.0f} ms",
        file=out,
    )


def _drive(cfg: DemoConfig, url: str, token: str, out: TextIO) -> int:
    """The demo's client side: plain HTTP against ``url``."""
    rng = np.random.default_rng(cfg.seed)
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=300.0) as client:
        r = client.get(f"/v1/cities/{cfg.city}")
        if r.status_code != 200:
            return _fail(r, f"GET city {cfg.city!r}")
        city = r.json()
        r = client.get(f"/v1/cities/{cfg.city}/graph")
        if r.status_code != 200:
            return _fail(r, "GET graph")
        nodes = r.json()["nodes"]
        node_ids = [int(n["id"]) for n in nodes]
        where = {int(n["id"]): (float(n["lon"]), float(n["lat"])) for n in nodes}
        hz = city["horizon"]
        tz = ZoneInfo(hz["timezone"])
        start = dt.datetime.combine(
            dt.date.fromisoformat(cfg.date), dt.time.fromisoformat(hz["start"]), tzinfo=tz
        )
        epoch_s = int(hz["epoch_s"])
        speed_mps = float(city["params"]["speed_kmh"]) / 3.6
        net = city["network"]
        print(
            f"city {cfg.city}: {net['nodes']} nodes, {net['edges']} edges, {net['road_km']:.0f} km of road; "
            f"grid {city['grid']['n_cols']} x {city['grid']['n_rows']} cells; seed {cfg.seed}",
            file=out,
        )

        def pick() -> int:
            return node_ids[int(rng.integers(len(node_ids)))]

        prefix = f"demo{cfg.seed}"
        tasks = [
            {
                "id": f"{prefix}-poi{i}",
                "location": {"node": pick()},
                "scheduled_at": (
                    start + dt.timedelta(seconds=int(rng.integers(-600, max(1, cfg.epochs) * epoch_s)))
                ).isoformat(),
            }
            for i in range(cfg.tasks)
        ]
        if tasks:
            r = client.post(f"/v1/cities/{cfg.city}/tasks", json=tasks)
            if r.status_code != 200:
                return _fail(r, "POST tasks")
            res = r.json()
            print(f"registered {len(tasks)} monitoring tasks ({len(res['created'])} new)", file=out)

        n_instr = round(cfg.taxis * cfg.instrumented_share)
        taxi_ids = [f"{prefix}-taxi{i:02d}" for i in range(cfg.taxis)]
        instrumented = {t: i < n_instr for i, t in enumerate(taxi_ids)}
        taxi_node = {t: pick() for t in taxi_ids}
        busy_until = {t: start for t in taxi_ids}
        waiting: dict[str, dict[str, object]] = {}
        last: dict[str, object] = {}
        for e in range(cfg.epochs):
            now = start + dt.timedelta(seconds=e * epoch_s)
            for j in range(cfg.riders):
                origin, dest = pick(), pick()
                while dest == origin and len(node_ids) > 1:
                    dest = pick()
                loc: dict[str, object] = {"node": origin}
                if j % 4 == 3:  # some riders come as GPS positions: a few metres off a node, snapped
                    lon, lat = where[origin]
                    loc = {"lon": lon + float(rng.normal(0, 1e-4)), "lat": lat + float(rng.normal(0, 1e-4))}
                rid = f"{prefix}-e{e}-r{j:02d}"
                requested = now - dt.timedelta(seconds=float(rng.uniform(0, epoch_s)))
                waiting[rid] = {
                    "id": rid,
                    "origin": loc,
                    "destination": {"node": dest},
                    "requested_at": requested.isoformat(timespec="seconds"),
                }
            taxis = [
                {
                    "id": t,
                    "location": {"node": taxi_node[t]},
                    "instrumented": instrumented[t],
                    "status": "busy" if busy_until[t] > now else "vacant",
                }
                for t in taxi_ids
            ]
            body = {
                "epoch_id": f"{prefix}-{cfg.date}-{e:03d}",
                "time": now.isoformat(),
                "riders": list(waiting.values()),
                "taxis": taxis,
            }
            r = client.post(f"/v1/cities/{cfg.city}/epochs", json=body)
            if r.status_code == 409 and r.json().get("error") == "stale_epoch":
                print(
                    "demo: the service already holds later epochs of this city; pass another --date",
                    file=sys.stderr,
                )
                return 1
            if r.status_code != 200:
                return _fail(r, f"POST epoch {e}")
            last = res = r.json()
            replay = (
                " (replayed: this epoch was committed before)" if r.headers.get("Idempotent-Replayed") else ""
            )
            n_vacant = sum(1 for t in taxis if t["status"] == "vacant")
            head = (
                f"epoch {e + 1}/{cfg.epochs} at {now:%H:%M:%S}{replay}: "
                f"{len(body['riders'])} riders waiting, {cfg.taxis} taxis "
                f"({n_vacant} vacant, {n_instr} instrumented)"
            )
            _print_epoch(out, head, res, prefix)
            for m in res["rider_matches"]:
                waiting.pop(m["rider_id"], None)
                busy_until[m["taxi_id"]] = now + dt.timedelta(seconds=m["wait_s"] + m["trip_m"] / speed_mps)
                taxi_node[m["taxi_id"]] = int(m["path"][-1])
            for a in res["task_assignments"]:
                busy_until[a["taxi_id"]] = now + dt.timedelta(seconds=a["travel_time_s"])
                taxi_node[a["taxi_id"]] = int(a["path"][-1])
            for rid in res["expired_rider_ids"]:
                waiting.pop(rid, None)

        if last:
            r = client.get(f"/v1/cities/{cfg.city}/coverage")
            if r.status_code == 200:
                cov = r.json()
                print(
                    f"\ncoverage of interval {cov['interval']}: {cov['n_cells_covered']} of "
                    f"{cov['n_cells_touched']} cells sensed ({cov['coverage_rate']:.0%}), "
                    f"Gamma so far {cov['gamma_so_far']:.5f}",
                    file=out,
                )
            r = client.get(f"/v1/cities/{cfg.city}/tasks")
            if r.status_code == 200:
                mine = [t for t in r.json()["tasks"] if t["id"].startswith(prefix + "-")]
                counts = {
                    s: sum(1 for t in mine if t["status"] == s) for s in ("pending", "assigned", "completed")
                }
                print(
                    f"tasks: {counts['completed']} completed, {counts['assigned']} on their way, "
                    f"{counts['pending']} pending",
                    file=out,
                )
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    import uvicorn

    from app.main import create_app

    settings = Settings()
    if args.host is not None or args.port is not None:
        settings = settings.model_copy(
            update={k: v for k, v in (("host", args.host), ("port", args.port)) if v is not None}
        )
    requested_host = settings.host
    settings, token = dev_settings(settings)
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    if token is not None:
        if requested_host not in _LOOPBACK:
            print(
                f"SD_TOKENS is not set: ignoring host {requested_host!r}, binding 127.0.0.1 only", flush=True
            )
        print(f"development token (scopes read, dispatch, admin): {token}", flush=True)
        print(
            f"  try: curl -H 'Authorization: Bearer {token}' http://127.0.0.1:{settings.port}/v1/cities",
            flush=True,
        )
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level=settings.log_level)
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    config = DemoConfig(
        city=args.city,
        epochs=args.epochs,
        riders=args.riders,
        taxis=args.taxis,
        instrumented_share=args.instrumented,
        tasks=args.tasks,
        seed=args.seed,
        date=args.date,
    )
    return run_demo(config, url=args.url, token=args.token)


def _cmd_openapi(args: argparse.Namespace) -> int:
    path = write_openapi(Path(args.out))
    print(f"wrote {path}")
    return 0


def _cmd_token(_: argparse.Namespace) -> int:
    print(new_token())
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m app", description="sensedispatch: drive-by sensing dispatch"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser("run", help="start the HTTP service (settings from SD_* environment variables)")
    run.add_argument("--host", default=None, help="bind address (default SD_HOST or 127.0.0.1)")
    run.add_argument("--port", type=int, default=None, help="port (default SD_PORT or 8000)")
    run.set_defaults(func=_cmd_run)

    demo = sub.add_parser("demo", help="post a few random epochs and print what was decided")
    demo.add_argument("--url", default=None, help="a running service (default: start one in-process)")
    demo.add_argument("--token", default=None, help="bearer token for --url (scopes read and dispatch)")
    demo.add_argument("--city", default="chengdu")
    demo.add_argument("--epochs", type=int, default=5)
    demo.add_argument("--riders", type=int, default=12, help="new riders per epoch")
    demo.add_argument("--taxis", type=int, default=30)
    demo.add_argument("--instrumented", type=float, default=0.5, help="share of instrumented taxis")
    demo.add_argument("--tasks", type=int, default=4, help="monitoring tasks to register")
    demo.add_argument("--seed", type=int, default=7)
    demo.add_argument("--date", default="2026-11-23", help="local date of the horizon to simulate")
    demo.set_defaults(func=_cmd_demo)

    api = sub.add_parser("openapi", help="write the OpenAPI document")
    api.add_argument("--out", default=str(OPENAPI_PATH), help=f"output file (default {OPENAPI_PATH})")
    api.set_defaults(func=_cmd_openapi)

    sub.add_parser(
        "import-city", help="build a city bundle from OSM XML or CSV (see import-city -h)", add_help=False
    )
    sub.add_parser("worker", help="the fleet-sizing worker", add_help=False)
    sub.add_parser(
        "experiment", help="the paper's numerical test, resumable (see experiment -h)", add_help=False
    )
    sub.add_parser("replay", help="simulate one horizon against the service (see replay -h)", add_help=False)
    sub.add_parser(
        "fleet-experiment", help="DRO fleet sizing on train/test days, the paper's Table 2", add_help=False
    )

    tok = sub.add_parser("token", help="print a fresh random bearer token")
    tok.set_defaults(func=_cmd_token)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m app`` and ``sensedispatch``; returns the exit code."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] == "import-city":
        from app.cities import import_city_cli

        return import_city_cli(args_list[1:], default_out=Settings().cities_dir)
    if args_list and args_list[0] in ("experiment", "fleet-experiment", "replay"):
        from app.experiment import cli as experiment_cli

        run = {
            "experiment": experiment_cli.experiment_main,
            "fleet-experiment": experiment_cli.fleet_experiment_main,
            "replay": experiment_cli.replay_main,
        }[args_list[0]]
        return run(args_list[1:])
    if args_list and args_list[0] == "worker":
        try:
            worker = importlib.import_module("app.worker")
        except ModuleNotFoundError:
            print(
                "python -m app worker: the fleet-sizing worker is not part of this build yet", file=sys.stderr
            )
            return 2
        return int(worker.main(args_list[1:]))
    args = _parser().parse_args(args_list)
    return int(args.func(args))
