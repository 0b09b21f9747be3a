"""The on-disk city bundle: writing a network and its ``city.json``, reading them back, building a
:class:`City` from them; the error every city-data reader raises (:class:`CityDataError`: the file, the row
or element, the problem). The importers of OSM XML, CSV and node-link JSON are ``services.importers``.

Bundle format (one directory per city)
--------------------------------------
``network.npz`` (``np.savez_compressed``)
    ``node_ids`` int64 (n,), ``lon``/``lat`` float64 (n,), ``edge_u``/``edge_v`` int32 (m,) node *indices*
    (or ``edge_u_id``/``edge_v_id`` int64 external ids instead), ``edge_length_m`` float64 (m,), optional
    ``edge_speed_kmh`` float64 (m,) (otherwise every edge runs at ``params.speed_kmh``).
``city.json``
    ``{"name", "timezone", "horizon": {"start": "08:00", "interval_s", "n_intervals", "epoch_s"},
    "params": {overrides of DispatchParams}, "cell_m": 1000, "source": attribution line,
    "built_with": {"script", "input", "sha256"}, "files": {role: file name in the bundle},
    "fleet": {the FleetParams set: "sizes", "n0", "days", "subsidy_cny_per_vehicle_hour",
    "completion_target"} (optional)}``.

The city built from a bundle weighs every cell the network touches equally (``s_g = 1/|touched|``, 0
elsewhere) and every interval of the horizon equally (``mu_t = 1/n_intervals``), docs/METHOD.md section 3.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import json
import math
import re
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import numpy as np
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from services.city import City, DispatchParams, FleetParams, Horizon
from services.network.network import Network, build_network
from services.sensing.grid import build_edge_cells, build_grid, touched_cells

__all__ = [
    "CityDataError",
    "CityMeta",
    "EARTH_RADIUS_M",
    "haversine_m",
    "validate_city_name",
    "save_bundle",
    "read_meta",
    "load_network",
    "load_city",
    "city_from_network",
    "sha256_of",
]

EARTH_RADIUS_M = 6_371_009.0
"""Mean Earth radius used for haversine lengths (the value OSMnx uses)."""

_CITY_NAME = re.compile(r"[a-z0-9_-]{1,40}")


class CityDataError(ValueError):
    """Input city data is malformed.

    Parameters
    ----------
    file : str
        The file's name (or path).
    row : int or None
        1-based data row (CSV, header excluded), line, or element number; None for whole-file problems.
    problem : str
        What is wrong.
    unit : str
        What ``row`` counts: ``"row"``, ``"line"``, ``"node"``, ``"link"``...
    """

    def __init__(self, file: str, row: int | None, problem: str, unit: str = "row") -> None:
        self.file = file
        self.row = row
        self.problem = problem
        self.unit = unit
        where = f"{file}, {unit} {row}" if row is not None else file
        super().__init__(f"{where}: {problem}")


def validate_city_name(name: str) -> str:
    """Return ``name`` if it is a valid city name (lowercase ``[a-z0-9_-]``, 1-40 characters).

    Raises
    ------
    ValueError
        Otherwise.
    """
    if not isinstance(name, str) or not _CITY_NAME.fullmatch(name):
        raise ValueError(f"invalid city name {name!r}: use 1-40 characters from a-z, 0-9, '_' and '-'")
    return name


def haversine_m(
    lon1: NDArray[np.float64] | float,
    lat1: NDArray[np.float64] | float,
    lon2: NDArray[np.float64] | float,
    lat2: NDArray[np.float64] | float,
) -> NDArray[np.float64]:
    """Great-circle distance in metres on a sphere of radius :data:`EARTH_RADIUS_M`."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dphi = p2 - p1
    dlam = np.radians(np.asarray(lon2) - np.asarray(lon1))
    a = np.sin(dphi / 2.0) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dlam / 2.0) ** 2
    return np.asarray(2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0))), dtype=np.float64)


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------- bundle


@dataclass(frozen=True, slots=True)
class CityMeta:
    """The contents of a bundle's ``city.json``.

    ``params`` holds overrides of :class:`services.city.DispatchParams` fields (JSON values; lists for
    tuples); ``fleet`` the :class:`services.city.FleetParams` set for the city. ``files`` maps a role
    (``"pois"``, ``"requests"``...) to a file name inside the bundle.
    """

    name: str
    timezone: str = "UTC"
    start: str = "08:00"
    interval_s: int = 3600
    n_intervals: int = 4
    epoch_s: int = 200
    params: dict[str, Any] = field(default_factory=dict)
    cell_m: float = 1000.0
    source: str = ""
    built_with: dict[str, Any] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)
    fleet: dict[str, Any] = field(default_factory=dict)

    def horizon(self) -> Horizon:
        """The :class:`Horizon` described (raises ``ValueError`` when invalid)."""
        try:
            ZoneInfo(self.timezone)
        except (ZoneInfoNotFoundError, ValueError, TypeError):
            raise ValueError(f"unknown timezone {self.timezone!r}") from None
        m = re.fullmatch(r"(\d{1,2}):(\d{2})", str(self.start))
        if not m or int(m.group(1)) > 23 or int(m.group(2)) > 59:
            raise ValueError(f"start must be HH:MM, got {self.start!r}")
        return Horizon(
            timezone=self.timezone,
            start=dt.time(int(m.group(1)), int(m.group(2))),
            interval_s=self.interval_s,
            n_intervals=self.n_intervals,
            epoch_s=self.epoch_s,
        )

    def dispatch_params(self) -> DispatchParams:
        """:class:`DispatchParams` with the overrides applied (raises ``ValueError`` when invalid)."""
        known = {f.name: f for f in dataclasses.fields(DispatchParams)}
        kwargs: dict[str, Any] = {}
        for key, value in self.params.items():
            if key not in known:
                raise ValueError(f"unknown dispatch parameter {key!r}")
            kwargs[key] = tuple(value) if isinstance(value, list) else value
        try:
            return DispatchParams(**kwargs)
        except TypeError as exc:
            raise ValueError(str(exc)) from None

    def fleet_params(self) -> FleetParams:
        """:class:`FleetParams` from ``fleet`` (raises ``ValueError`` when invalid)."""
        known = {f.name for f in dataclasses.fields(FleetParams)}
        unknown = sorted(set(self.fleet) - known)
        if unknown:
            raise ValueError(
                f"unknown fleet parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        kwargs: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in self.fleet.items() if v is not None
        }
        return FleetParams(**kwargs)

    def validate(self) -> None:
        """Raise ``ValueError`` if any field is invalid."""
        validate_city_name(self.name)
        self.horizon()
        self.dispatch_params()
        self.fleet_params()
        if not (isinstance(self.cell_m, int | float) and math.isfinite(self.cell_m) and self.cell_m > 0):
            raise ValueError("cell_m must be positive")

    def to_json(self) -> dict[str, Any]:
        """The ``city.json`` object."""
        return {
            "name": self.name,
            "timezone": self.timezone,
            "horizon": {
                "start": self.start,
                "interval_s": self.interval_s,
                "n_intervals": self.n_intervals,
                "epoch_s": self.epoch_s,
            },
            "params": dict(self.params),
            "cell_m": self.cell_m,
            "source": self.source,
            "built_with": dict(self.built_with),
            "files": dict(self.files),
            **({"fleet": dict(self.fleet)} if self.fleet else {}),
        }

    @classmethod
    def from_json(cls, obj: Any) -> CityMeta:
        """Parse a ``city.json`` object (raises ``ValueError`` naming the problem)."""
        if not isinstance(obj, dict):
            raise ValueError("expected a JSON object")
        extra = set(obj) - {
            "name",
            "timezone",
            "horizon",
            "params",
            "cell_m",
            "source",
            "built_with",
            "files",
            "fleet",
        }
        if extra:
            raise ValueError(f"unknown key(s) {', '.join(sorted(extra))}")
        hz = obj.get("horizon", {})
        if not isinstance(hz, dict) or set(hz) - {"start", "interval_s", "n_intervals", "epoch_s"}:
            raise ValueError("horizon must be an object with start, interval_s, n_intervals, epoch_s")
        for key in ("params", "built_with", "files", "fleet"):
            if not isinstance(obj.get(key, {}), dict):
                raise ValueError(f"{key} must be an object")
        for key in ("interval_s", "n_intervals", "epoch_s"):
            if key in hz and (isinstance(hz[key], bool) or not isinstance(hz[key], int)):
                raise ValueError(f"horizon.{key} must be an integer")
        if "name" not in obj:
            raise ValueError("missing 'name'")
        meta = cls(
            name=obj["name"],
            timezone=obj.get("timezone", "UTC"),
            start=hz.get("start", "08:00"),
            interval_s=hz.get("interval_s", 3600),
            n_intervals=hz.get("n_intervals", 4),
            epoch_s=hz.get("epoch_s", 200),
            params=dict(obj.get("params", {})),
            cell_m=obj.get("cell_m", 1000.0),
            source=obj.get("source", ""),
            built_with=dict(obj.get("built_with", {})),
            files=dict(obj.get("files", {})),
            fleet=dict(obj.get("fleet", {})),
        )
        meta.validate()
        return meta


def _write_npz(path: Path, arrays: Mapping[str, NDArray[Any]]) -> None:
    """What ``np.savez_compressed`` writes, with fixed timestamps so rebuilding gives identical bytes."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, arr in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arr), allow_pickle=False)


def save_bundle(directory: Path | str, network: Network, meta: CityMeta) -> Path:
    """Write ``network.npz`` and ``city.json`` into ``directory`` (created if needed).

    Returns
    -------
    Path
        The directory.
    """
    meta.validate()
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, NDArray[Any]] = {
        "node_ids": network.node_ids.astype(np.int64),
        "lon": network.lon.astype(np.float64),
        "lat": network.lat.astype(np.float64),
        "edge_u": network.edge_u.astype(np.int32),
        "edge_v": network.edge_v.astype(np.int32),
        "edge_length_m": network.edge_length_m.astype(np.float64),
    }
    # per-edge speeds are stored only where the network does not run at the city's one speed
    speed_kmh = meta.dispatch_params().speed_kmh
    expected_s = network.edge_length_m / (speed_kmh / 3.6)
    if not np.allclose(network.edge_time_s, expected_s, rtol=1e-9, atol=1e-9):
        with np.errstate(divide="ignore", invalid="ignore"):
            speed = network.edge_length_m / network.edge_time_s * 3.6
        arrays["edge_speed_kmh"] = np.where(np.isfinite(speed) & (speed > 0), speed, np.nan)
    _write_npz(d / "network.npz", arrays)
    (d / "city.json").write_text(json.dumps(meta.to_json(), indent=2, ensure_ascii=False) + "\n", "utf-8")
    return d


def read_meta(directory: Path | str) -> CityMeta:
    """Parse a bundle's ``city.json``.

    Raises
    ------
    CityDataError
        If it is missing or invalid.
    """
    path = Path(directory) / "city.json"
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CityDataError(str(path), None, f"cannot read: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise CityDataError(str(path), exc.lineno, f"malformed JSON ({exc.msg})", unit="line") from None
    try:
        return CityMeta.from_json(obj)
    except ValueError as exc:
        raise CityDataError(str(path), None, str(exc)) from None


def load_network(directory: Path | str, default_speed_kmh: float = 35.0) -> Network:
    """Build the :class:`Network` of a bundle's ``network.npz``.

    Raises
    ------
    CityDataError
        If the file is missing, lacks arrays, holds invalid values or is not strongly connected.
    """
    path = Path(directory) / "network.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise CityDataError(str(path), None, f"cannot read: {exc}") from None
    need = {"node_ids", "lon", "lat", "edge_length_m"}
    missing = need - set(arrays)
    if missing:
        raise CityDataError(str(path), None, f"missing array(s) {', '.join(sorted(missing))}")
    ids = arrays["node_ids"]
    try:
        if "edge_u" in arrays and "edge_v" in arrays:
            eu, ev = arrays["edge_u"].astype(np.int64), arrays["edge_v"].astype(np.int64)
            if eu.size and (min(eu.min(), ev.min()) < 0 or max(eu.max(), ev.max()) >= ids.size):
                raise ValueError("edge node index out of range")
            u_ids, v_ids = ids[eu], ids[ev]
        elif "edge_u_id" in arrays and "edge_v_id" in arrays:
            u_ids, v_ids = arrays["edge_u_id"], arrays["edge_v_id"]
        else:
            raise ValueError("missing edge_u/edge_v (or edge_u_id/edge_v_id)")
        net = build_network(
            ids,
            arrays["lon"],
            arrays["lat"],
            u_ids,
            v_ids,
            arrays["edge_length_m"],
            arrays.get("edge_speed_kmh"),
            default_speed_kmh,
        )
    except ValueError as exc:
        raise CityDataError(str(path), None, str(exc)) from None
    n_comp, _ = connected_components(
        net.csr(np.ones(net.n_edges)), directed=True, connection="strong", return_labels=True
    )
    if n_comp != 1:
        raise CityDataError(str(path), None, f"network is not strongly connected ({n_comp} components)")
    return net


def city_from_network(network: Network, meta: CityMeta) -> City:
    """Assemble a :class:`City`: grid, edge cells, uniform cell and interval weights, horizon, params."""
    try:
        horizon = meta.horizon()
        params = meta.dispatch_params()
        fleet = meta.fleet_params()
    except ValueError as exc:
        raise CityDataError("city.json", None, str(exc)) from None
    grid = build_grid(network, float(meta.cell_m))
    edge_cells = build_edge_cells(grid, network)
    touched = touched_cells(grid, network, edge_cells)
    cell_weight = np.zeros(grid.n_cells, dtype=np.float64)
    cell_weight[touched] = 1.0 / touched.size
    interval_weight = np.full(horizon.n_intervals, 1.0 / horizon.n_intervals)
    return City(
        name=meta.name,
        network=network,
        grid=grid,
        edge_cells=edge_cells,
        horizon=horizon,
        params=params,
        cell_weight=cell_weight,
        interval_weight=interval_weight,
        source=meta.source,
        fleet=fleet,
    )


def load_city(directory: Path | str) -> City:
    """Load a city bundle (``network.npz`` + ``city.json``) into a :class:`City`.

    Raises
    ------
    CityDataError
        If either file is missing or invalid (e.g. ``fleet.synthetic_history`` without the POIs or
        recorded requests a demand generator draws from).
    """
    meta = read_meta(directory)
    if meta.fleet.get("synthetic_history") and not {"pois", "requests"} & set(meta.files):
        raise CityDataError(
            "city.json",
            None,
            "fleet.synthetic_history needs a demand generator: files.pois or files.requests",
        )
    network = load_network(directory, default_speed_kmh=meta.dispatch_params().speed_kmh)
    return city_from_network(network, meta)
