"""The served cities: bundled ones shipped in ``app/data/cities`` and user-imported ones in a directory
(``CityRegistry``, the use cases' ``CityCatalog``), and building a bundle from OSM XML or CSV
(``import_city``; its command line is ``app.entrypoints.import_city``)."""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

from app.errors import UnknownCity
from app.settings import Settings
from services.city import City
from services.citydata import CityDataError, CityMeta, load_city, save_bundle, sha256_of, validate_city_name
from services.importers import ImportResult, read_csv_network, read_osm

__all__ = [
    "BUNDLED_DIR",
    "CityRegistry",
    "ImportKind",
    "import_city",
]

BUNDLED_DIR = Path(__file__).resolve().parents[1] / "data" / "cities"
"""Bundled city bundles shipped with the package."""

ImportKind = Literal["osm", "csv"]


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
        return cls(settings.cities.bundled_dir or BUNDLED_DIR, settings.cities.user_dir)

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


def import_city(
    kind: ImportKind,
    inputs: Sequence[Path | str],
    meta: CityMeta,
    out_root: Path | str,
    *,
    overwrite: bool = False,
) -> tuple[Path, ImportResult, City]:
    """Build a city bundle from OSM XML (``inputs=[file.osm]``) or CSV (``inputs=[nodes.csv, edges.csv]``).

    ``meta`` names the city and holds its horizon, cell size, dispatch parameters and source (its
    ``built_with`` is filled in here). The bundle is written to ``out_root/<meta.name>/``; a
    :class:`CityRegistry` whose ``user_dir`` is ``out_root`` serves it by name. Returns the bundle's
    directory, what was read and the city as loaded back.

    Raises
    ------
    ValueError
        On an invalid name, timezone, start or parameter.
    CityDataError
        On bad input data (naming file, row and problem).
    FileExistsError
        If the city exists and ``overwrite`` is false.
    """
    validate_city_name(meta.name)
    name = meta.name
    paths = [Path(p) for p in inputs]
    meta = dataclasses.replace(
        meta,
        params=dict(meta.params),
        fleet=dict(meta.fleet),
        built_with={
            "script": f"app.adapters.city_registry.import_city(kind={kind!r})",
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
