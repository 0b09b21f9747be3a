"""Synthetic Chengdu demand calibrated to measured DiDi facts (docs/METHOD.md section 10, "Demand data").

No open trip records exist for the paper's district, so the requests are synthetic, made from three
ingredients and labelled ``generator="chengdu-synthetic"``:

* **when** -- hourly Poisson counts following the measured profile 54 : 79 : 55 : 59 (08-12 h), scaled so
  the mean is ``rate_per_hour`` (about 144), times a daily volume factor (lognormal with mean 1 and
  log-standard deviation ``volume_sd``); request times uniform whole seconds within the hour;
* **where from** -- an origin density over the network's nodes: a Gaussian kernel density of the OSM
  points of interest in the projected plane (bandwidth ``bandwidth_m``) evaluated at every node, mixed with
  a uniform ``background`` share so that every node can be an origin (:func:`poi_density`). Day-to-day
  spatial jitter multiplies each POI's weight by a lognormal factor (mean 1, log-sd ``jitter_sd``);
* **where to** -- a straight-line trip length ``L`` drawn from the piecewise-linear quantile function
  through the measured quantiles (P10 1.8, P25 3.0, P50 5.4, P75 8.1, P90 11.7 km; P0 1.0 and P100
  14.1 km by extending the end segments), then a destination among the nodes whose distance from the
  origin is within ``max(5 % of L, 100 m)`` of ``L``, weighted by the same density (destinations are
  attracted by the same POIs). When no node is that far from the origin, the destination is among the
  farthest nodes (within the same band of the farthest distance): the trip is as long as the network
  allows from that origin.

**The box cannot host the longest trips.** The network spans about 9.4 x 9.4 km; its longest straight
line between two nodes is 11.8 km, so the measured P90 of 11.7 km (a sample that includes trips leaving
the 2nd ring) cannot be reproduced: over 100 days of seed 0 the achieved quantiles are P10 1.79,
P25 3.01, P50 5.41, P75 7.24 and P90 8.70 km (docs/DEMAND.md). Lengths up to the median match; P75
falls 11 % short and P90 26 % short. Drawing the origin again until the long trip fits would move origins to
the corners and still miss P90 (about 9.9 km after 100 retries), so origins keep their density instead.

**Scenarios** (same requests, different destinations for some of them). Scenario ``s`` has a remote
share ``p_s`` (``0``, ``0.2``, ``0.4`` for 1, 2, 3): each request carries a uniform number ``u``; when
``u < p_s`` its destination is drawn instead among the nodes of the *remote cells* (the quarter of the grid
cells holding nodes with the lowest origin density, :class:`PoiDensity`) with the same length rule. Every
draw is made whatever the scenario, so scenarios 1-3 of one ``(seed, day)`` share times, origins and trip
lengths, scenario 3 moves a superset of the requests scenario 2 moves, and the volume is identical: the
scenarios differ only in space, as docs/METHOD.md section 10 asks. The random streams therefore derive from
``(seed, day)``; the scenario selects ``p_s``.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from services.city import City, Horizon
from services.sensing.grid import cells_of_points
from services.sim.demand import DemandFileError, DemandSet, Request, demand_rng

__all__ = [
    "GENERATOR",
    "HOURLY_PROFILE",
    "LENGTH_QUANTILES_KM",
    "SCENARIO_REMOTE_SHARE",
    "DemandShape",
    "PoiDensity",
    "chengdu_demand",
    "length_quantile_m",
    "pick_destinations",
    "poi_density",
    "read_pois_csv",
]

GENERATOR = "chengdu-synthetic"
_STREAM = 0xC4E6  # keeps this generator's random numbers apart from other users of the same seed

HOURLY_PROFILE: tuple[float, ...] = (54.0, 79.0, 55.0, 59.0)
"""Relative request volume of 08, 09, 10, 11 h (DiDi Chengdu sample, 2016-11-02)."""

LENGTH_QUANTILES_KM: tuple[tuple[float, float], ...] = (
    (0.0, 1.0),
    (0.10, 1.8),
    (0.25, 3.0),
    (0.50, 5.4),
    (0.75, 8.1),
    (0.90, 11.7),
    (1.0, 14.1),
)
"""(probability, km) knots of the straight-line trip length's quantile function: the measured P10-P90 and
the end segments extended linearly to P0 and P100."""

SCENARIO_REMOTE_SHARE: dict[int, float] = {1: 0.0, 2: 0.2, 3: 0.4}
"""Share of requests whose destination is moved into a remote cell, per scenario."""


@dataclass(frozen=True, slots=True, eq=False)
class PoiDensity:
    """Origin density over a city's nodes built from points of interest, and its remote cells.

    Attributes
    ----------
    kernel : sparse (n_nodes, n_pois)
        Gaussian kernel ``exp(-d^2 / 2h^2)`` between nodes and POIs, cut at ``3h``.
    node_weight : float64 (n_nodes,)
        Base origin probability of each node (no jitter): ``(1 - background) * kde / sum(kde) +
        background / n_nodes``; sums to 1.
    node_cell : int64 (n_nodes,)
        Grid cell of each node.
    cell_weight : float64 (n_cells,)
        Base origin probability of each cell (the sum over its nodes; 0 for cells without nodes).
    remote_cell : bool (n_cells,)
        Cells holding at least one node whose ``cell_weight`` is at most the ``remote_quantile`` quantile
        of ``cell_weight`` over such cells: the cells of low request density.
    remote_node : bool (n_nodes,)
        Nodes inside remote cells.
    """

    kernel: sp.csr_matrix
    node_weight: NDArray[np.float64]
    node_cell: NDArray[np.int64]
    cell_weight: NDArray[np.float64]
    remote_cell: NDArray[np.bool_]
    remote_node: NDArray[np.bool_]
    n_pois: int
    bandwidth_m: float
    background: float
    remote_quantile: float

    def weights(self, poi_factor: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Node probabilities with each POI's weight multiplied by ``poi_factor`` (None: all 1)."""
        return _node_weights(self.kernel, poi_factor, self.background)


def _node_weights(
    kernel: sp.csr_matrix, poi_factor: NDArray[np.float64] | None, background: float
) -> NDArray[np.float64]:
    v = np.ones(kernel.shape[1]) if poi_factor is None else np.asarray(poi_factor, dtype=np.float64)
    kde = np.asarray(kernel @ v, dtype=np.float64)
    n = kde.shape[0]
    total = float(kde.sum())
    if total <= 0.0:  # no POI near any node: background only
        return np.full(n, 1.0 / n)
    w = (1.0 - background) * kde / total + background / n
    return np.asarray(w / w.sum(), dtype=np.float64)


def read_pois_csv(path: Path | str) -> NDArray[np.float64]:
    """Read the lon/lat of a points-of-interest CSV file (columns ``lon`` and ``lat``; others ignored).

    Returns
    -------
    float64 (n, 2)
        WGS84 lon, lat per row.

    Raises
    ------
    DemandFileError
        Naming the file and the row (1-based, header excluded) of a missing column or a bad number.
    """
    path = Path(path)
    name = path.name
    out: list[tuple[float, float]] = []
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            fields = reader.fieldnames or []
            missing = [c for c in ("lon", "lat") if c not in fields]
            if missing:
                raise DemandFileError(name, None, f"missing column(s) {', '.join(missing)}")
            for row, rec in enumerate(reader, start=1):
                try:
                    lon, lat = float(rec["lon"]), float(rec["lat"])
                except (TypeError, ValueError):
                    problem = f"lon/lat must be numbers: {rec['lon']!r}, {rec['lat']!r}"
                    raise DemandFileError(name, row, problem) from None
                if not (math.isfinite(lon) and math.isfinite(lat) and abs(lon) <= 180 and abs(lat) <= 90):
                    raise DemandFileError(name, row, f"not a WGS84 position: ({lon}, {lat})")
                out.append((lon, lat))
    except OSError as exc:
        raise DemandFileError(name, None, f"cannot read: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DemandFileError(name, None, f"not a UTF-8 CSV file ({exc})") from None
    if not out:
        raise DemandFileError(name, None, "no POI rows")
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def poi_density(
    city: City,
    poi_lonlat: ArrayLike,
    *,
    bandwidth_m: float = 500.0,
    background: float = 0.1,
    remote_quantile: float = 0.25,
) -> PoiDensity:
    """Build the origin density of a city from points of interest.

    Parameters
    ----------
    city : City
    poi_lonlat : float (n, 2)
        WGS84 lon, lat of the POIs (:func:`read_pois_csv`).
    bandwidth_m : float
        Standard deviation of the Gaussian kernel in projected metres.
    background : float
        Share of the density spread evenly over the nodes, in ``[0, 1]``.
    remote_quantile : float
        Cells (with nodes) at or below this quantile of origin density are remote, in ``(0, 1)``.
    """
    pois = np.asarray(poi_lonlat, dtype=np.float64)
    if pois.ndim != 2 or pois.shape[1] != 2 or pois.shape[0] == 0:
        raise ValueError("poi_lonlat must be a non-empty (n, 2) array of lon, lat")
    if not (bandwidth_m > 0 and 0.0 <= background <= 1.0 and 0.0 < remote_quantile < 1.0):
        raise ValueError("need bandwidth_m > 0, background in [0, 1] and remote_quantile in (0, 1)")
    net = city.network
    px, py = net.project(pois[:, 0], pois[:, 1])
    nodes_tree = cKDTree(np.column_stack([net.x_m, net.y_m]))
    poi_tree = cKDTree(np.column_stack([np.atleast_1d(px), np.atleast_1d(py)]))
    dist = nodes_tree.sparse_distance_matrix(poi_tree, 3.0 * bandwidth_m, output_type="coo_matrix")
    # sparse_distance_matrix leaves out pairs at distance 0; add them back explicitly
    d0 = nodes_tree.query_ball_tree(poi_tree, 1e-9)
    rows = [dist.row] + [np.full(len(js), i) for i, js in enumerate(d0) if js]
    cols = [dist.col] + [np.asarray(js) for js in d0 if js]
    vals = [np.exp(-0.5 * (dist.data / bandwidth_m) ** 2)] + [np.ones(len(js)) for js in d0 if js]
    kernel = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(net.n_nodes, len(pois))
    )
    w = _node_weights(kernel, None, float(background))
    node_cell = cells_of_points(city.grid, net.x_m, net.y_m)
    cell_w = np.bincount(node_cell, weights=w, minlength=city.grid.n_cells).astype(np.float64)
    occupied = np.bincount(node_cell, minlength=city.grid.n_cells) > 0
    cut = float(np.quantile(cell_w[occupied], remote_quantile))
    remote_cell = occupied & (cell_w <= cut)
    return PoiDensity(
        kernel=kernel,
        node_weight=w,
        node_cell=node_cell,
        cell_weight=cell_w,
        remote_cell=remote_cell,
        remote_node=remote_cell[node_cell],
        n_pois=len(pois),
        bandwidth_m=float(bandwidth_m),
        background=float(background),
        remote_quantile=float(remote_quantile),
    )


def length_quantile_m(
    u: ArrayLike, knots_km: Sequence[tuple[float, float]] = LENGTH_QUANTILES_KM
) -> NDArray[np.float64]:
    """Trip length in metres at probability ``u``: the piecewise-linear quantile function through
    ``knots_km`` (increasing probabilities from 0 to 1 and non-decreasing km)."""
    p = np.array([k[0] for k in knots_km], dtype=np.float64)
    q = np.array([k[1] for k in knots_km], dtype=np.float64)
    if p[0] != 0.0 or p[-1] != 1.0 or np.any(np.diff(p) <= 0) or np.any(np.diff(q) < 0) or q[0] < 0:
        raise ValueError("knots must run from probability 0 to 1 with non-decreasing non-negative km")
    return np.asarray(np.interp(np.asarray(u, dtype=np.float64), p, q) * 1000.0, dtype=np.float64)


def pick_destinations(
    x_m: NDArray[np.float64],
    y_m: NDArray[np.float64],
    origins: NDArray[np.int64],
    lengths_m: NDArray[np.float64],
    u: NDArray[np.float64],
    weight: NDArray[np.float64],
    allowed: NDArray[np.bool_] | None = None,
    *,
    band_rel: float = 0.05,
    band_min_m: float = 100.0,
    batch: int = 256,
) -> NDArray[np.int64]:
    """Destination of each request by the length rule (see the module docstring).

    For request ``i`` the candidates are the allowed nodes other than the origin whose straight-line
    distance ``d`` from the origin satisfies ``|d - L_i| <= g_i + band_i``, where ``g_i`` is the smallest
    ``|d - L_i|`` over the allowed nodes and ``band_i = max(band_rel * L_i, band_min_m)``; one candidate
    is taken with probability proportional to ``weight`` by inverse transform of ``u_i``.

    Returns
    -------
    int64 (k,)
        Node indices (``-1`` where no node is allowed).
    """
    n_req = origins.shape[0]
    out = np.full(n_req, -1, dtype=np.int64)
    ok = np.ones(x_m.shape[0], dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    cols = np.flatnonzero(ok)
    if cols.size == 0 or n_req == 0:
        return out
    # float32 distances: millimetre precision over a city, half the memory traffic of float64
    xs, ys = x_m[cols].astype(np.float32), y_m[cols].astype(np.float32)
    ws = np.asarray(weight, dtype=np.float64)[cols]
    for lo in range(0, n_req, batch):
        hi = min(lo + batch, n_req)
        o = origins[lo:hi]
        length = lengths_m[lo:hi, None].astype(np.float32)
        ox, oy = x_m[o, None].astype(np.float32), y_m[o, None].astype(np.float32)
        gap = np.hypot(xs[None, :] - ox, ys[None, :] - oy)
        gap -= length
        np.abs(gap, out=gap)
        pos = np.minimum(np.searchsorted(cols, o), cols.size - 1)
        own = np.flatnonzero(cols[pos] == o)
        gap[own, pos[own]] = np.inf  # never the origin itself
        g = gap.min(axis=1)
        g[~np.isfinite(g)] = -np.inf  # only the origin is allowed: no candidate
        band = np.maximum(band_rel * length[:, 0], np.float32(band_min_m))
        row, col = np.nonzero(gap <= (g + band)[:, None])  # candidates, row by row
        wc = ws[col]
        tot = np.bincount(row, weights=wc, minlength=hi - lo)
        cnt = np.bincount(row, minlength=hi - lo)
        flat = (tot <= 0.0) & (cnt > 0)  # every candidate of the row has weight 0: take them uniformly
        wc = np.where(flat[row], 1.0, wc)
        tot = np.where(flat, cnt, tot)
        start = np.cumsum(cnt) - cnt
        cum = np.concatenate(([0.0], np.cumsum(wc)))  # cum[start[i]]: weight before row i
        j = np.searchsorted(cum[1:], cum[start] + u[lo:hi] * tot, side="right")
        j = np.clip(j, start, start + cnt - 1)  # rounding at a row's last candidate
        found = cnt > 0
        out[lo:hi][found] = cols[col[j[found]]]
    return out


@dataclass(frozen=True, slots=True)
class DemandShape:
    """How much demand a synthetic day holds and how it varies (:func:`chengdu_demand`).

    Attributes
    ----------
    rate_per_hour : mean requests per hour over the horizon (before the daily volume factor).
    profile : relative volume of each interval (length ``n_intervals``).
    volume_sd, jitter_sd : log-standard deviations of the daily volume factor and of each POI's daily
        weight factor (lognormal with mean 1); 0 switches the variation off. Applied on every day, day 0
        included.
    remote_shares : scenario -> share of requests moved to remote cells (None: :data:`SCENARIO_REMOTE_SHARE`).
    length_quantiles_km : knots (probability, km) of the trip-length quantile function.
    """

    rate_per_hour: float = 144.0
    profile: Sequence[float] = HOURLY_PROFILE
    volume_sd: float = 0.1
    jitter_sd: float = 0.5
    remote_shares: Mapping[int, float] | None = None
    length_quantiles_km: Sequence[tuple[float, float]] = LENGTH_QUANTILES_KM


def _checked_shape(shape: DemandShape, scenario: int, n_intervals: int) -> tuple[NDArray[np.float64], float]:
    """The shape's profile as an array and the scenario's remote share, both checked."""
    shares = SCENARIO_REMOTE_SHARE if shape.remote_shares is None else shape.remote_shares
    if scenario not in shares:
        raise ValueError(f"unknown scenario {scenario!r} (known: {sorted(shares)})")
    share = float(shares[scenario])
    prof = np.asarray(shape.profile, dtype=np.float64)
    if prof.shape != (n_intervals,) or np.any(prof < 0) or prof.sum() <= 0:
        raise ValueError(f"profile must hold {n_intervals} non-negative numbers, not all 0")
    if not (
        shape.rate_per_hour >= 0 and shape.volume_sd >= 0 and shape.jitter_sd >= 0 and 0.0 <= share <= 1.0
    ):
        raise ValueError("rate_per_hour, volume_sd, jitter_sd must be >= 0 and the remote share in [0, 1]")
    return prof, share


def _day_volume(
    stream: np.random.SeedSequence, shape: DemandShape, horizon: Horizon, prof: NDArray[np.float64]
) -> tuple[float, NDArray[np.float64], NDArray[np.int64]]:
    """The day's volume factor, the expected requests per interval before it and the drawn counts."""
    rng = np.random.default_rng(stream)
    volume_sd = shape.volume_sd
    factor = float(np.exp(volume_sd * rng.standard_normal() - 0.5 * volume_sd**2))
    hours = horizon.interval_s / 3600.0
    expected = shape.rate_per_hour * hours * horizon.n_intervals * prof / prof.sum()
    counts: NDArray[np.int64] = rng.poisson(factor * expected)
    return factor, expected, counts


def _request_times(
    stream: np.random.SeedSequence, horizon: Horizon, date: str, counts: NDArray[np.int64]
) -> NDArray[np.int64]:
    """``counts[k]`` request times in whole seconds, uniform within interval ``k``, ascending."""
    rng = np.random.default_rng(stream)
    start_s = horizon.start_s(date)
    times = np.concatenate(
        [
            start_s + k * horizon.interval_s + rng.integers(0, horizon.interval_s, size=c)
            for k, c in enumerate(counts)
        ]
    )
    times.sort()
    return times


def _origins(
    stream: np.random.SeedSequence, density: PoiDensity, jitter_sd: float, n: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The day's node weights (each POI's weight jittered) and ``n`` origins drawn from them."""
    rng = np.random.default_rng(stream)
    poi_factor = np.exp(jitter_sd * rng.standard_normal(density.n_pois) - 0.5 * jitter_sd**2)
    w = density.weights(poi_factor)
    origins: NDArray[np.int64] = np.asarray(rng.choice(w.shape[0], size=n, p=w), dtype=np.int64)
    return w, origins


def _destinations(
    city: City,
    density: PoiDensity,
    w: NDArray[np.float64],
    origins: NDArray[np.int64],
    lengths: NDArray[np.float64],
    streams: tuple[np.random.SeedSequence, np.random.SeedSequence],
    share: float,
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Each request's destination by the length rule, and which of them were moved to a remote cell (the
    request's uniform number below ``share``); ``streams`` draw the destinations and the moves."""
    n = int(origins.shape[0])
    u_dest: NDArray[np.float64] = np.random.default_rng(streams[0]).random(n)
    rng = np.random.default_rng(streams[1])
    u_move: NDArray[np.float64] = rng.random(n)
    u_remote: NDArray[np.float64] = rng.random(n)
    net = city.network
    moved = u_move < share
    dest = np.empty(n, dtype=np.int64)
    keep = ~moved
    dest[keep] = pick_destinations(net.x_m, net.y_m, origins[keep], lengths[keep], u_dest[keep], w)
    if moved.any():
        dest[moved] = pick_destinations(
            net.x_m, net.y_m, origins[moved], lengths[moved], u_remote[moved], w, density.remote_node
        )
    if np.any(dest < 0):
        raise ValueError("no remote node to move destinations to")
    return dest, moved


def chengdu_demand(
    city: City,
    pois: ArrayLike | PoiDensity,
    *,
    seed: int,
    scenario: int = 1,
    day: int = 0,
    date: str = "2016-11-02",
    shape: DemandShape = DemandShape(),
) -> DemandSet:
    """One day of synthetic requests over the city's horizon (module docstring: how and how well).

    Parameters
    ----------
    city : City
        Its horizon fixes the intervals (``n_intervals`` of ``interval_s`` from ``start``, local time).
    pois : float (n, 2) or PoiDensity
        POI lon/lat, or the density already built from them by :func:`poi_density` (reuse it across days).
    seed : int
        Non-negative; with ``day`` it fixes every random number (the scenario does not, see above).
    scenario : int
        Key of ``remote_shares`` (1, 2, 3 by default: 0, 20 and 40 % of destinations moved to remote cells).
    day : int
        Non-negative; each day is an independent draw (volume factor, jitter, requests).
    date : str
        Local calendar date ``YYYY-MM-DD`` the requests are placed on.
    shape : DemandShape
        The volume, its profile and variation, the scenarios' remote shares and the trip lengths.

    Returns
    -------
    DemandSet
        ``generator="chengdu-synthetic"``, ``seed=seed``; ``params`` records scenario, day, rate, profile,
        the drawn volume factor, the expected count per interval, the density settings and the number of
        requests whose destination was moved to a remote cell. Ids are ``d{day}-{i:05d}`` in time order.
    """
    hz = city.horizon
    prof, share = _checked_shape(shape, scenario, hz.n_intervals)
    density = pois if isinstance(pois, PoiDensity) else poi_density(city, pois)
    if density.node_weight.shape[0] != city.network.n_nodes:
        raise ValueError("the POI density was built for another network")

    s_volume, s_times, s_space, s_length, s_dest, s_remote = demand_rng(_STREAM, seed, day).spawn(6)
    factor, expected, counts = _day_volume(s_volume, shape, hz, prof)
    times = _request_times(s_times, hz, date, counts)
    n = int(times.shape[0])
    w, origins = _origins(s_space, density, shape.jitter_sd, n)
    lengths = length_quantile_m(np.random.default_rng(s_length).random(n), shape.length_quantiles_km)
    dest, moved = _destinations(city, density, w, origins, lengths, (s_dest, s_remote), share)

    requests = tuple(
        Request(f"d{day}-{i:05d}", float(t), int(o), int(d))
        for i, (t, o, d) in enumerate(zip(times.tolist(), origins.tolist(), dest.tolist(), strict=True))
    )
    params = {
        "scenario": int(scenario),
        "day": int(day),
        "rate_per_hour": float(shape.rate_per_hour),
        "profile": [float(p) for p in prof],
        "volume_sd": float(shape.volume_sd),
        "volume_factor": factor,
        "expected_per_interval": [float(e) for e in factor * expected],
        "jitter_sd": float(shape.jitter_sd),
        "remote_share": share,
        "n_moved_remote": int(moved.sum()),
        "length_quantiles_km": [[float(p), float(q)] for p, q in shape.length_quantiles_km],
        "bandwidth_m": density.bandwidth_m,
        "background": density.background,
        "remote_quantile": density.remote_quantile,
        "n_pois": density.n_pois,
    }
    return DemandSet(city.name, date, requests, GENERATOR, seed=int(seed), params=params)
