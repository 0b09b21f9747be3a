"""Command line: ``python -m app COMMAND`` (run, demo, replay, worker, import-city, openapi, token)."""

from __future__ import annotations

import argparse
import json
import secrets
import sys
from collections.abc import Sequence
from pathlib import Path

from app.settings import Settings

__all__ = [
    "main",
    "new_token",
    "dev_settings",
    "openapi_document",
    "write_openapi",
    "OPENAPI_PATH",
]

_MOVED = ("experiment", "fleet-experiment")  # now `python -m research ...`
OPENAPI_PATH = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"
_LOOPBACK = {"127.0.0.1", "localhost", "::1"}


def new_token() -> str:
    """A fresh random bearer token, ``sd_`` and 43 URL-safe characters: never starting with ``-``, so that it
    can follow an option on a command line (``replay --token $TOKEN``)."""
    return "sd_" + secrets.token_urlsafe(32)


def dev_settings(settings: Settings) -> tuple[Settings, str | None]:
    """With no configured tokens: add a random token with every scope and bind loopback only."""
    if settings.auth.tokens:
        return settings, None
    token = new_token()
    return settings.with_values(tokens={token: ["read", "dispatch", "admin"]}, host="127.0.0.1"), token


def openapi_document() -> str:
    """The OpenAPI document of the app, as committed in ``openapi/openapi.json``."""
    from app.adapters.memory_store import MemoryStore
    from app.bootstrap import create_app

    app = create_app(Settings().with_values(tokens={}, store="memory"), store=MemoryStore())
    return json.dumps(app.openapi(), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def write_openapi(path: Path = OPENAPI_PATH) -> Path:
    """Write the OpenAPI document to ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(openapi_document(), encoding="utf-8")
    return path


def _cmd_run(args: argparse.Namespace) -> int:
    import logging.config

    import uvicorn

    from app.bootstrap import create_app
    from app.entrypoints.server import server_config, tune_allocator
    from app.logs import log_config

    tune_allocator()
    settings = Settings()
    if args.host is not None or args.port is not None:
        given = {k: v for k, v in (("host", args.host), ("port", args.port)) if v is not None}
        settings = settings.with_values(**given)
    requested_host = settings.server.host
    settings, token = dev_settings(settings)
    logging.config.dictConfig(log_config(settings.log_level))
    if token is not None:
        if requested_host not in _LOOPBACK:
            print(
                f"SD_TOKENS is not set: ignoring host {requested_host!r}, binding 127.0.0.1 only", flush=True
            )
        print(f"development token (scopes read, dispatch, admin): {token}", flush=True)
        print(
            f"  try: curl -H 'Authorization: Bearer {token}' http://127.0.0.1:{settings.server.port}/v1/cities",
            flush=True,
        )
    embed = settings.embeds_worker()
    if embed:
        print(
            "fleet worker: running inside the service (memory store; SD_WORKER_EMBEDDED=off leaves it "
            "out): it solves before every hour of the horizon and on POST .../fleet/solve",
            flush=True,
        )
    app = create_app(settings, tune_gc=True, embed_worker=embed, compile_apart=True)
    uvicorn.Server(server_config(app, settings)).run()
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from app.entrypoints.demo import DemoConfig, run_demo

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

    demo = sub.add_parser(
        "demo", help="post the first epochs of a simulated morning and print what was decided"
    )
    demo.add_argument("--url", default=None, help="a running service (default: start one in-process)")
    demo.add_argument("--token", default=None, help="bearer token for --url (scopes read and dispatch)")
    demo.add_argument("--city", default="chengdu")
    demo.add_argument("--epochs", type=int, default=5)
    demo.add_argument("--riders", type=int, default=12, help="new riders per epoch (mean)")
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
    sub.add_parser("replay", help="simulate one horizon against the service (see replay -h)", add_help=False)

    tok = sub.add_parser("token", help="print a fresh random bearer token")
    tok.set_defaults(func=_cmd_token)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m app`` and ``sensedispatch``; returns the exit code."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] == "import-city":
        from app.entrypoints.import_city import import_city_cli

        return import_city_cli(args_list[1:], default_out=Settings().cities.user_dir)
    if args_list and args_list[0] == "replay":
        from app.entrypoints.replay import replay_main

        return replay_main(args_list[1:])
    if args_list and args_list[0] == "worker":
        from app.entrypoints.worker import main as worker_main

        return worker_main(args_list[1:])
    if args_list and args_list[0] in _MOVED:
        print(
            f"python -m app {args_list[0]}: the experiments moved to the research package: "
            f"python -m research {args_list[0]} (pip install 'sensedispatch[research]')",
            file=sys.stderr,
        )
        return 2
    args = _parser().parse_args(args_list)
    return int(args.func(args))
