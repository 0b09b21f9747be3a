"""``python -m app import-city``: build a city bundle from OSM XML or CSV
(``app.adapters.city_registry.import_city``) into the settings' user cities directory."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from app.adapters.city_registry import ImportKind, import_city
from services.citydata import CityDataError, CityMeta

__all__ = ["import_city_cli"]


def _named_values(items: Sequence[str], flag: str) -> dict[str, Any]:
    """``NAME=JSON`` arguments as a dict (``ValueError`` naming the flag and the item)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        try:
            if not sep:
                raise ValueError("expected NAME=JSON")
            out[key.strip()] = json.loads(text)
        except ValueError as exc:
            raise ValueError(f"{flag} {item!r}: {exc}") from None
    return out


def _import_parser(default_out: Path | None) -> argparse.ArgumentParser:
    """The ``import-city`` command line."""
    parser = argparse.ArgumentParser(
        prog="import-city", description="Build a city bundle from OSM XML or CSV (nodes.csv, edges.csv)."
    )
    parser.add_argument("name", help="city name: lowercase a-z, 0-9, '_' or '-', at most 40 characters")
    parser.add_argument("--osm", type=Path, help="OSM XML file")
    parser.add_argument("--nodes", type=Path, help="nodes.csv (id,lon,lat)")
    parser.add_argument("--edges", type=Path, help="edges.csv (u,v,length_m[,speed_kmh])")
    parser.add_argument("--timezone", default="UTC", help="IANA timezone of the city (default UTC)")
    parser.add_argument("--start", default="08:00", help="local start of the sensing horizon, HH:MM")
    parser.add_argument("--intervals", type=int, default=4, help="number of sensing intervals (default 4)")
    parser.add_argument("--interval-s", type=int, default=3600, help="interval length in seconds")
    parser.add_argument("--cell-m", type=float, default=1000.0, help="grid cell side in metres")
    parser.add_argument("--source", default="", help="attribution line for the data")
    parser.add_argument("--out", type=Path, default=default_out, help="directory of imported cities")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing city of that name")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=JSON",
        help="a dispatch parameter of the city (docs/METHOD.md), e.g. step3_reach_s=600 or "
        "step3_reach_s=null; repeat for more",
    )
    parser.add_argument(
        "--fleet",
        action="append",
        default=[],
        metavar="NAME=JSON",
        help="a fleet-sizing parameter of the city (docs/FLEET.md, 'Per city'): sizes=[100,200,400], n0=450, "
        "days=10, subsidy_cny_per_vehicle_hour=0.94 or completion_target=0.9; repeat for more",
    )
    return parser


def import_city_cli(
    argv: Sequence[str],
    default_out: Path | None = None,
    stdout: TextIO | None = None,
    stderr: TextIO | None = None,
) -> int:
    """``import-city NAME --osm FILE | --nodes nodes.csv --edges edges.csv [...]``; returns the exit code.

    ``argv`` holds the arguments after the sub-command. Without ``--out`` the bundle goes to
    ``default_out`` (the caller passes the settings' user cities directory).
    """
    out = stdout or sys.stdout
    err = stderr or sys.stderr
    parser = _import_parser(default_out)
    try:
        args = parser.parse_args(list(argv))
    except SystemExit as exc:  # argparse has printed the usage
        return int(exc.code or 0) if isinstance(exc.code, int) else 2

    kind: ImportKind
    if args.osm is not None and args.nodes is None and args.edges is None:
        kind, inputs = "osm", [args.osm]
    elif args.osm is None and args.nodes is not None and args.edges is not None:
        kind, inputs = "csv", [args.nodes, args.edges]
    else:
        print("import-city: give either --osm FILE or both --nodes and --edges", file=err)
        return 2
    if args.out is None:
        print("import-city: --out DIR is required", file=err)
        return 2
    try:
        params = _named_values(args.param, "--param")
        fleet = _named_values(args.fleet, "--fleet")
    except ValueError as exc:
        print(f"import-city: {exc}", file=err)
        return 2
    try:
        meta = CityMeta(
            name=args.name,
            timezone=args.timezone,
            start=args.start,
            interval_s=args.interval_s,
            n_intervals=args.intervals,
            epoch_s=200,
            params=params,
            cell_m=args.cell_m,
            source=args.source,
            fleet=fleet,
        )
        target, result, city = import_city(kind, inputs, meta, args.out, overwrite=args.overwrite)
    except CityDataError as exc:
        print(f"import-city: {exc}", file=err)
        return 1
    except (ValueError, FileExistsError) as exc:
        print(f"import-city: {exc}", file=err)
        return 2
    g = city.grid
    print(
        f"imported {args.name!r}: {result.summary()}; grid {g.n_cols} x {g.n_rows} cells of "
        f"{g.cell_m:.0f} m ({g.crs}) -> {target}",
        file=out,
    )
    return 0
