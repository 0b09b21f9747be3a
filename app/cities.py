"""The served cities: bundled ones shipped in ``app/data/cities`` and user-imported ones in a directory."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal, TextIO

from app.errors import UnknownCityError
from app.settings import Settings
from services.city import City
from services.citydata import CityDataError, CityMeta, load_city, save_bundle, sha256_of, validate_city_name
from services.importers import ImportResult, read_csv_network, read_osm

__all__ = [
    "BUNDLED_DIR",
    "UnknownCity",
    "CityRegistry",
    "import_city",
    "import_city_cli",
]

BUNDLED_DIR = Path(__file__).resolve().parent / "data" / "cities"
"""Bundled city bundles shipped with the package."""

ImportKind = Literal["osm", "csv"]


class UnknownCity(UnknownCityError, KeyError):
    """No city of that name is served (a ``KeyError`` and a 404 ``unknown_city``)."""

    def __str__(self) -> str:
        return self.detail


def _is_bundle(path: Path) -> bool:
    return (path / "city.json").is_file() and (path / "network.npz").is_file()


class CityRegistry:
    """Cities by name, loaded on first use and kept.

    A user directory's city shadows a bundled city of the same name. Directory names are the city names;
    a bundle whose ``city.json`` names another city is refused. Thread-safe.

    Parameters
    ----------
    bundled_dir : Path
        Directory of bundled cities (one sub-directory each).
    user_dir : Path, optional
        Directory of imported cities; need not exist yet.
    """

    def __init__(self, bundled_dir: Path = BUNDLED_DIR, user_dir: Path | None = None) -> None:
        self.bundled_dir = Path(bundled_dir)
        self.user_dir = Path(user_dir) if user_dir is not None else None
        self._cache: dict[str, City] = {}
        self._lock = threading.Lock()

    @classmethod
    def from_settings(cls, settings: Settings) -> CityRegistry:
        """The one registry of a deployment: bundled cities (``SD_BUNDLED_CITIES_DIR``, default the
        package's) and imported ones (``SD_CITIES_DIR``). The API, the worker and the CLIs all use it."""
        return cls(settings.bundled_cities_dir or BUNDLED_DIR, settings.cities_dir)

    def _roots(self) -> list[Path]:
        # the user directory first: it shadows bundled cities
        return [r for r in (self.user_dir, self.bundled_dir) if r is not None]

    def names(self) -> list[str]:
        """Sorted names of every city with a bundle on disk."""
        found: set[str] = set()
        for root in self._roots():
            if root.is_dir():
                for sub in root.iterdir():
                    if sub.is_dir() and _is_bundle(sub) and _valid(sub.name):
                        found.add(sub.name)
        return sorted(found)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and _valid(name) and self._find(name) is not None

    def _find(self, name: str) -> Path | None:
        for root in self._roots():
            if _is_bundle(root / name):
                return root / name
        return None

    def bundle_dir(self, name: str) -> Path:
        """The directory of a city's bundle (for its extra files, e.g. POIs).

        Raises
        ------
        UnknownCity
        """
        path = self._find(name) if _valid(name) else None
        if path is None:
            raise UnknownCity(f"unknown city {name!r}; served: {', '.join(self.names()) or 'none'}")
        return path

    def get(self, name: str) -> City:
        """The city called ``name``, loading it on first use.

        Raises
        ------
        UnknownCity
            If no bundle has that name.
        CityDataError
            If its bundle is invalid.
        """
        city = self._cache.get(name)
        if city is not None:
            return city
        path = self.bundle_dir(name)
        with self._lock:
            city = self._cache.get(name)
            if city is None:
                city = load_city(path)
                if city.name != name:
                    raise CityDataError(
                        str(path / "city.json"), None, f"names city {city.name!r}, not {name!r}"
                    )
                self._cache[name] = city
        return city

    def load_all(self) -> dict[str, City]:
        """Load every city now (e.g. at start-up, to fail early)."""
        return {name: self.get(name) for name in self.names()}

    def forget(self, name: str | None = None) -> None:
        """Drop a loaded city (or all) so the next :meth:`get` reads its bundle again."""
        with self._lock:
            if name is None:
                self._cache.clear()
            else:
                self._cache.pop(name, None)


def _valid(name: str) -> bool:
    try:
        validate_city_name(name)
    except ValueError:
        return False
    return True


def _read(kind: str, inputs: Sequence[Path], default_speed_kmh: float) -> ImportResult:
    if kind == "osm":
        if len(inputs) != 1:
            raise ValueError("an OSM import takes exactly one input file")
        return read_osm(inputs[0], default_speed_kmh)
    if kind == "csv":
        if len(inputs) != 2:
            raise ValueError("a CSV import takes two input files: nodes.csv and edges.csv")
        return read_csv_network(inputs[0], inputs[1], default_speed_kmh)
    raise ValueError(f"unknown import kind {kind!r} (expected 'osm' or 'csv')")


def _import(
    kind: ImportKind, inputs: Sequence[Path | str], meta: CityMeta, out_root: Path | str, *, overwrite: bool
) -> tuple[Path, ImportResult, City]:
    validate_city_name(meta.name)
    name = meta.name
    paths = [Path(p) for p in inputs]
    meta = dataclasses.replace(
        meta,
        params=dict(meta.params),
        fleet=dict(meta.fleet),
        built_with={
            "script": f"app.cities.import_city(kind={kind!r})",
            "input": paths[0].name if len(paths) == 1 else [p.name for p in paths],
            "sha256": (
                (sha256_of(paths[0]) if len(paths) == 1 else [sha256_of(p) for p in paths])
                if all(p.is_file() for p in paths)
                else ""
            ),
        },
    )
    meta.validate()  # before the heavy work: a bad timezone or start fails fast
    target = Path(out_root) / name
    if target.exists() and not overwrite:
        raise FileExistsError(f"city {name!r} already exists at {target}")
    result = _read(kind, paths, meta.dispatch_params().speed_kmh)
    Path(out_root).mkdir(parents=True, exist_ok=True)
    # write next to the target and rename, so a reader never sees half a bundle
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=out_root))
    try:
        save_bundle(tmp, result.network, meta)
        city = load_city(tmp)
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target, result, city


def import_city(
    kind: ImportKind,
    inputs: Sequence[Path | str],
    meta: CityMeta,
    out_root: Path | str,
    *,
    overwrite: bool = False,
) -> Path:
    """Build a city bundle from OSM XML (``inputs=[file.osm]``) or CSV (``inputs=[nodes.csv, edges.csv]``).

    ``meta`` names the city and holds its horizon, cell size, dispatch parameters and source (its
    ``built_with`` is filled in here). The bundle is written to ``out_root/<meta.name>/``; a
    :class:`CityRegistry` whose ``user_dir`` is ``out_root`` serves it by name.

    Raises
    ------
    ValueError
        On an invalid name, timezone, start or parameter.
    CityDataError
        On bad input data (naming file, row and problem).
    FileExistsError
        If the city exists and ``overwrite`` is false.
    """
    target, _, _ = _import(kind, inputs, meta, out_root, overwrite=overwrite)
    return target


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
        target, result, city = _import(kind, inputs, meta, args.out, overwrite=args.overwrite)
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
