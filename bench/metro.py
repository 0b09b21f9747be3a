"""A generated metropolitan road network for the benchmarks: ``metro_city`` (code only, no data file).

A 70 x 70 km square (at ``scale`` 1) centred on 104.06 E, 30.66 N, drawn in a plane of metres and laid on the
sphere by a sinusoidal projection about its middle. Every random draw comes from the seed.

* Density: five urban centres (:func:`centres`; the main one in the middle, four smaller ones towards the
  corners) whose weighted Gaussians (sigma 5.6-9.8 km) give every superblock an urbanity, times lognormal
  noise (sigma 0.22) so that density is patchy: urban, suburban and rural superblocks (638, 932 and 1,346).
* Arterials, 50 km/h: an irregular mesh, a 55 x 55 lattice of junctions about 1.3 km apart, jittered
  (sigma 13 %), bent by a smooth warp, its sides bowed; 15 % of the inner sides are demoted to local streets
  (so its cells are 1.3-2.6 km). Between rural superblocks the sides are country roads at 60 km/h, and half of
  those no street reaches are left out: long roads between villages.
* Local streets, 30 km/h: in every superblock a jittered lattice mapped onto its quadrilateral. Urban blocks
  84-132 m (6 % of the pieces missing), suburban blocks 135-230 m with winding streets (13 % missing); 30 %
  of those superblocks hold a park (2-3 x 2-3 blocks merged); 2 % / 6 % of the pieces are cut in the middle
  into two cul-de-sacs. A rural superblock holds a village in one corner (85-120 m blocks, 40 %) and/or a
  lane across (60 %). Streets from either side of an arterial meet it at different points (T-junctions)
  unless within 25 m of each other. 20 % of the urban and 10 % of the suburban streets (a whole line of a
  superblock each) are one-way, never into a dead end.
* Bends: pieces get intermediate nodes off the chord (degree-2 chains; one per ~800 m of urban street,
  ~450 m of suburban, ~350 m of rural street or country road, ~450 m of arterial), and every edge's length is
  its chord times 1 + 0.3 U^2 (U uniform: 0-30 % longer, 10 % on average).
* A river 220 m wide meanders west to east through the main centre (:func:`river`): nothing in it and no road
  across it but six arterial bridges (three or more when scaled down), at least 2.9 km apart and drawn
  towards the centres, and the motorways.
* Motorways, 90 km/h, dual carriageways (two one-way chains 36 m apart, a node every 400 m): a ring of radius
  ~21.7 km round the main centre and four radials from 4.9 km out to the edge of the square. Junctions every
  2-4 km (none within 800 m of the river or 1.5 km of an interchange) join both carriageways to the nearest
  arterial node by one-way ramps at 40 km/h; interchanges join the radials to the ring.

The city is the largest strongly connected part of that. As built with ``SEED`` at scale 1 (``python -m
bench.metro`` prints these): 259,720 nodes and 710,122 directed edges (2.73 a node); 70.7 x 70.4 km in UTM
48N (lon 103.69-104.43, lat 30.35-30.97), 52 nodes per km2; edges 1,452 motorway, 396 ramp, 86,590
arterial, 31,032 country road and 590,652 local (83 %); 44,820 one-way edges (13.6 % of the local streets
one-way); 16,341 dead ends (6.3 % of the nodes); nodes with 2, 3 and 4+ distinct neighbours 32.3, 25.9 and
35.5 %; the river crossed at 8 places (6 bridges and the ring twice). ``metro_city()`` takes about 2 s on the
2-core machine (more while other work runs), the command's peak resident memory about 440 MB; at ``scale``
0.18, 7,983 nodes and 20,963 edges in 0.05 s.

    python -m bench.metro [--seed N] [--scale S]     # build it, print these counts and the build time
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from bench.load import Centres
from services.city import City
from services.citydata import EARTH_RADIUS_M, CityMeta, city_from_network, haversine_m
from services.network.network import build_network, largest_strongly_connected

__all__ = [
    "shuffled",
    "SEED",
    "SIDE_M",
    "centres",
    "describe",
    "metro_city",
    "near_centres",
    "river",
    "river_crossings",
]

SEED = 20260501
SIDE_M = 70_000.0  # side of the square city at scale 1
CENTRE_LONLAT = (104.06, 30.66)  # lon, lat of the middle of the square
ARTERIAL_PITCH_M = 1_300.0  # mean spacing of the arterial mesh (not scaled)
RIVER_WIDTH_M = 220.0
MOTORWAY_STEP_M = 400.0  # shape nodes along a carriageway
CARRIAGEWAY_OFFSET_M = 18.0  # each carriageway this far from the motorway's axis

# road classes and their speeds in km/h
LOCAL, ARTERIAL, COUNTRY, MOTORWAY, RAMP = 0, 1, 2, 3, 4
SPEED_KMH = np.array([30.0, 50.0, 60.0, 90.0, 40.0])
# settings of a superblock (and of the streets in it)
URBAN, SUBURBAN, RURAL = 0, 1, 2

# the centres: x, y as fractions of the side, weight, radius (Gaussian sigma) as a fraction of the side
_CENTRES = np.array(
    [
        (0.50, 0.53, 1.00, 0.140),
        (0.23, 0.72, 0.80, 0.090),
        (0.77, 0.30, 0.80, 0.095),
        (0.28, 0.26, 0.65, 0.080),
        (0.76, 0.76, 0.65, 0.080),
    ]
)
_RADIAL_DEG = (55.0, 125.0, 240.0, 305.0)

# per setting (urban, suburban, rural): share of local edges dropped, of local lines one-way, of local edges
# cut in the middle (two cul-de-sacs), chord per shape node (m), sigma of the bow (share of the chord)
_DROP = (0.06, 0.13, 0.0)
_ONE_WAY = (0.20, 0.10, 0.0)
_CUT = (0.02, 0.06, 0.03)
_SHAPE_M = (800.0, 450.0, 350.0)
_BOW = (0.04, 0.09, 0.07)
_ARTERIAL_SHAPE_M = 450.0
_COUNTRY_SHAPE_M = 350.0


@dataclass
class _Layout:
    side: float
    centres: NDArray[np.float64]  # (k, 4): x m, y m, weight, sigma m
    river_phase: NDArray[np.float64]  # (3,)

    def urbanity(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        """In [0, 1]: the largest weighted Gaussian of the distance to a centre."""
        u = np.zeros(np.shape(x))
        for cx, cy, w, s in self.centres:
            u = np.maximum(u, w * np.exp(-0.5 * ((x - cx) ** 2 + (y - cy) ** 2) / s**2))
        return u

    def river_y(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """The river's centre line, y as a function of x (it flows west to east across the city)."""
        side = self.side
        p = self.river_phase
        y = side * (
            0.50
            + 0.030 * np.sin(2 * np.pi * x / (0.61 * side) + p[0])
            + 0.014 * np.sin(2 * np.pi * x / (0.23 * side) + p[1])
            + 0.005 * np.sin(2 * np.pi * x / (0.09 * side) + p[2])
        )
        return np.asarray(y, dtype=np.float64)


def _layout(seed: int, scale: float) -> _Layout:
    if not (0.05 <= scale <= 2.0):
        raise ValueError(f"scale must lie in [0.05, 2], got {scale}")
    side = SIDE_M * scale
    rng = np.random.default_rng([seed, 1])
    c = _CENTRES.copy()
    c[:, 0] *= side
    c[:, 1] *= side
    c[:, 3] *= side
    return _Layout(side=side, centres=c, river_phase=rng.uniform(0.0, 2 * np.pi, 3))


@dataclass
class _Roads:
    """Nodes (x, y in the city's plane) and undirected road pieces with their attributes."""

    x: list[NDArray[np.float64]] = field(default_factory=list)
    y: list[NDArray[np.float64]] = field(default_factory=list)
    n: int = 0
    a: list[NDArray[np.int64]] = field(default_factory=list)
    b: list[NDArray[np.int64]] = field(default_factory=list)
    cls: list[NDArray[np.int64]] = field(default_factory=list)
    setting: list[NDArray[np.int64]] = field(default_factory=list)
    line: list[NDArray[np.int64]] = field(default_factory=list)  # one-way group (-1: none)
    side: list[NDArray[np.int64]] = field(default_factory=list)  # arterial side (-1: none)

    def nodes(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.int64]:
        ids = np.arange(self.n, self.n + x.size, dtype=np.int64)
        self.x.append(np.asarray(x, dtype=np.float64))
        self.y.append(np.asarray(y, dtype=np.float64))
        self.n += x.size
        return ids

    def edges(
        self,
        a: NDArray[np.int64],
        b: NDArray[np.int64],
        cls: int,
        setting: int,
        line: NDArray[np.int64] | int = -1,
        side: int = -1,
    ) -> None:
        k = a.size
        self.a.append(a)
        self.b.append(b)
        self.cls.append(np.full(k, cls, dtype=np.int64))
        self.setting.append(np.full(k, setting, dtype=np.int64))
        self.line.append(np.broadcast_to(np.asarray(line, dtype=np.int64), (k,)).copy())
        self.side.append(np.full(k, side, dtype=np.int64))


@dataclass
class _Block:
    setting: int
    xs: NDArray[np.float64]  # interior lines' parameters along s (0..1 from the left side)
    ys: NDArray[np.float64]  # along t (0..1 from the bottom side)
    hkeep: NDArray[np.bool_]  # (len(ys), len(xs) + 1): row b + 1, piece a
    vkeep: NDArray[np.bool_]  # (len(xs), len(ys) + 1): column a + 1, piece b


def _lines(rng: np.random.Generator, k: int) -> NDArray[np.float64]:
    """k - 1 interior parameters of k roughly equal intervals, jittered and sorted."""
    if k < 2:
        return np.zeros(0)
    return np.sort((np.arange(1, k) + rng.uniform(-0.22, 0.22, k - 1)) / k)


def _plan_block(rng: np.random.Generator, u: float, w: float, h: float) -> _Block:
    """The local streets of one superblock of urbanity ``u`` and sides ``w`` x ``h`` metres."""
    if u >= 0.42:
        setting = URBAN
        spacing = 84.0 + 48.0 * (1.0 - u) / 0.58
    elif u >= 0.11:
        setting = SUBURBAN
        spacing = 135.0 + 95.0 * (0.42 - u) / 0.31
    else:
        setting = RURAL
        spacing = 0.0
    if setting != RURAL:
        kx = max(2, round(w / spacing * rng.uniform(0.85, 1.15)))
        ky = max(2, round(h / spacing * rng.uniform(0.85, 1.15)))
        xs, ys = _lines(rng, kx), _lines(rng, ky)
        hkeep = rng.random((ky - 1, kx)) >= _DROP[setting]
        vkeep = rng.random((kx - 1, ky)) >= _DROP[setting]
        if kx >= 5 and ky >= 5 and rng.random() < 0.3:  # a park, a campus or a rail yard
            sa, sb = rng.integers(2, 4, 2)
            a0, b0 = rng.integers(0, kx - sa), rng.integers(0, ky - sb)
            # lattice nodes strictly inside [a0, a0 + sa] x [b0, b0 + sb] lose all their pieces
            rows = np.arange(1, ky)[:, None]
            cols = np.arange(kx)[None, :]
            inside_row = (rows > b0) & (rows < b0 + sb)
            hkeep &= ~(inside_row & (cols + 1 > a0) & (cols < a0 + sa))
            vcols = np.arange(1, kx)[:, None]
            vrows = np.arange(ky)[None, :]
            inside_col = (vcols > a0) & (vcols < a0 + sa)
            vkeep &= ~(inside_col & (vrows + 1 > b0) & (vrows < b0 + sb))
        return _Block(setting, xs, ys, hkeep, vkeep)

    # rural: maybe a village in one corner, maybe a lane across
    xs_l: list[float] = []
    ys_l: list[float] = []
    fx = fy = 0.0
    flip_x, flip_y = bool(rng.random() < 0.5), bool(rng.random() < 0.5)
    if rng.random() < 0.4:
        fx, fy = rng.uniform(0.2, 0.42, 2)
        vs = rng.uniform(85.0, 120.0)
        nx, ny = max(2, round(fx * w / vs)), max(2, round(fy * h / vs))
        xs_l += list(fx * np.arange(1, nx + 1) / nx)
        ys_l += list(fy * np.arange(1, ny + 1) / ny)
    lane_x = lane_y = -1.0
    r = rng.random()
    if r < 0.3:
        lane_x = float(rng.uniform(0.55, 0.8))
        xs_l.append(lane_x)
    elif r < 0.6:
        lane_y = float(rng.uniform(0.55, 0.8))
        ys_l.append(lane_y)
    xs = np.sort(np.array(xs_l, dtype=np.float64))
    ys = np.sort(np.array(ys_l, dtype=np.float64))
    sx = np.concatenate([[0.0], xs, [1.0]])
    sy = np.concatenate([[0.0], ys, [1.0]])
    in_x = sx <= fx + 1e-9
    in_y = sy <= fy + 1e-9
    # pieces between lattice nodes, inside the village or on the lane
    hk = (in_y[1:-1, None] & in_x[None, :-1] & in_x[None, 1:]) | (sy[1:-1, None] == lane_y)
    vk = (in_x[1:-1, None] & in_y[None, :-1] & in_y[None, 1:]) | (sx[1:-1, None] == lane_x)
    hk = np.broadcast_to(hk, (ys.size, xs.size + 1)).copy()
    vk = np.broadcast_to(vk, (xs.size, ys.size + 1)).copy()
    # the village sits in a random corner
    if flip_x:
        xs = 1.0 - xs[::-1]
        hk, vk = hk[:, ::-1], vk[::-1, :]
    if flip_y:
        ys = 1.0 - ys[::-1]
        hk, vk = hk[::-1, :], vk[:, ::-1]
    return _Block(RURAL, xs, ys, np.ascontiguousarray(hk), np.ascontiguousarray(vk))


def _merge_side(
    t_a: NDArray[np.float64], t_b: NDArray[np.float64], length: float
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Points asked for on a side by the blocks on either side, those closer than 25 m made one.

    Returns the merged parameters and, for every asked point of each block, its merged point.
    """
    t = np.concatenate([t_a, t_b])
    if t.size == 0:
        return t, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    ts = t[order]
    new = np.ones(ts.size, dtype=bool)
    new[1:] = (ts[1:] - ts[:-1]) * length > 25.0
    cluster_sorted = np.cumsum(new) - 1
    cluster = np.empty(t.size, dtype=np.int64)
    cluster[order] = cluster_sorted
    merged = np.bincount(cluster_sorted, ts) / np.bincount(cluster_sorted)
    return merged, cluster[: t_a.size], cluster[t_a.size :]


def _bilinear(
    corners: NDArray[np.float64], s: NDArray[np.float64], t: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points of the quadrilateral ``corners`` = (p00, p10, p01, p11) at parameters (s, t)."""
    p00, p10, p01, p11 = corners
    w00, w10, w01, w11 = (1 - s) * (1 - t), s * (1 - t), (1 - s) * t, s * t
    x = w00 * p00[0] + w10 * p10[0] + w01 * p01[0] + w11 * p11[0]
    y = w00 * p00[1] + w10 * p10[1] + w01 * p01[1] + w11 * p11[1]
    return x, y


def _streets(lay: _Layout, rng: np.random.Generator, roads: _Roads) -> NDArray[np.int64]:
    """The arterial mesh and the local streets of every superblock. Returns each side's class."""
    side = lay.side
    nb = max(3, round(side / ARTERIAL_PITCH_M))
    pitch = side / nb
    nj = nb + 1
    gi, gj = np.meshgrid(np.arange(nj), np.arange(nj), indexing="ij")
    jx = gi * pitch + rng.normal(0.0, 0.13 * pitch, gi.shape).clip(-0.3 * pitch, 0.3 * pitch)
    jy = gj * pitch + rng.normal(0.0, 0.13 * pitch, gi.shape).clip(-0.3 * pitch, 0.3 * pitch)
    # a smooth warp bends the long arterials
    ph = rng.uniform(0.0, 2 * np.pi, 4)
    lam = 9_000.0
    jx = jx + 0.2 * pitch * np.sin(2 * np.pi * jy / lam + ph[0]) * np.sin(
        2 * np.pi * jx / (1.7 * lam) + ph[1]
    )
    jy = jy + 0.2 * pitch * np.sin(2 * np.pi * jx / lam + ph[2]) * np.sin(
        2 * np.pi * jy / (1.3 * lam) + ph[3]
    )
    jx[0, :], jx[-1, :], jy[:, 0], jy[:, -1] = 0.0, side, 0.0, side
    jx, jy = jx.clip(0.0, side), jy.clip(0.0, side)
    jid = roads.nodes(jx.ravel(), jy.ravel()).reshape(nj, nj)

    # sides: horizontal h = i * nj + j from J[i, j] to J[i + 1, j]; vertical nb * nj + i * nb + j from
    # J[i, j] to J[i, j + 1]
    n_h = nb * nj
    n_sides = 2 * nb * nj

    def h_side(i: int, j: int) -> int:
        return i * nj + j

    def v_side(i: int, j: int) -> int:
        return n_h + i * nb + j

    side_ends = np.empty((n_sides, 2), dtype=np.int64)
    for i in range(nb):
        for j in range(nj):
            side_ends[h_side(i, j)] = (jid[i, j], jid[i + 1, j])
    for i in range(nj):
        for j in range(nb):
            side_ends[v_side(i, j)] = (jid[i, j], jid[i, j + 1])
    pos = np.column_stack([jx.ravel(), jy.ravel()])
    p0, p1 = pos[side_ends[:, 0]], pos[side_ends[:, 1]]
    side_len = np.hypot(*(p1 - p0).T)

    # plan every block
    cx = 0.25 * (jx[:-1, :-1] + jx[1:, :-1] + jx[:-1, 1:] + jx[1:, 1:])
    cy = 0.25 * (jy[:-1, :-1] + jy[1:, :-1] + jy[:-1, 1:] + jy[1:, 1:])
    u = np.minimum(lay.urbanity(cx, cy) * np.exp(rng.normal(0.0, 0.22, cx.shape)), 1.0)
    blocks: list[list[_Block]] = []
    for i in range(nb):
        row: list[_Block] = []
        for j in range(nb):
            w = 0.5 * (side_len[h_side(i, j)] + side_len[h_side(i, j + 1)])
            h = 0.5 * (side_len[v_side(i, j)] + side_len[v_side(i + 1, j)])
            row.append(_plan_block(rng, float(u[i, j]), w, h))
        blocks.append(row)

    # points asked for on each side: (parameters, block, which) per side, at most two
    asks: list[list[tuple[NDArray[np.float64], int, int]]] = [[] for _ in range(n_sides)]
    for i in range(nb):
        for j in range(nb):
            bl = blocks[i][j]
            asks[h_side(i, j)].append((bl.xs[bl.vkeep[:, 0]] if bl.xs.size else bl.xs, i * nb + j, 0))
            asks[h_side(i, j + 1)].append((bl.xs[bl.vkeep[:, -1]] if bl.xs.size else bl.xs, i * nb + j, 1))
            asks[v_side(i, j)].append((bl.ys[bl.hkeep[:, 0]] if bl.ys.size else bl.ys, i * nb + j, 2))
            asks[v_side(i + 1, j)].append((bl.ys[bl.hkeep[:, -1]] if bl.ys.size else bl.ys, i * nb + j, 3))

    # side classes: country roads between rural blocks, arterials elsewhere, a few demoted to local streets
    setting = np.array([[bl.setting for bl in row] for row in blocks])
    side_setting = np.full(n_sides, RURAL, dtype=np.int64)
    for i in range(nb):
        for j in range(nb):
            s = setting[i, j]
            for sd in (h_side(i, j), h_side(i, j + 1), v_side(i, j), v_side(i + 1, j)):
                side_setting[sd] = min(side_setting[sd], s)
    border = np.zeros(n_sides, dtype=bool)
    for i in range(nb):
        border[h_side(i, 0)] = border[h_side(i, nb)] = True
    for j in range(nb):
        border[v_side(0, j)] = border[v_side(nb, j)] = True
    side_cls = np.where(side_setting == RURAL, COUNTRY, ARTERIAL)
    draw = rng.random(n_sides)
    side_cls[(side_setting != RURAL) & ~border & (draw < 0.15)] = LOCAL
    asked = np.array([sum(a[0].size for a in asks[sd]) for sd in range(n_sides)])
    dropped = (side_setting == RURAL) & (asked == 0) & (draw > 0.5)

    # merge the asks into side nodes; a side is a gently bowed line between its junctions
    answer: dict[tuple[int, int], NDArray[np.int64]] = {}
    bows = rng.normal(0.0, 0.015, n_sides)
    for sd in range(n_sides):
        ask = asks[sd]
        t_a = ask[0][0]
        t_b = ask[1][0] if len(ask) > 1 else np.zeros(0)
        merged, ca, cb = _merge_side(t_a, t_b, float(side_len[sd]))
        d = p1[sd] - p0[sd]
        normal = np.array([-d[1], d[0]])
        px = p0[sd, 0] + merged * d[0] + bows[sd] * np.sin(np.pi * merged) * normal[0]
        py = p0[sd, 1] + merged * d[1] + bows[sd] * np.sin(np.pi * merged) * normal[1]
        ids = roads.nodes(px, py)
        answer[(ask[0][1], ask[0][2])] = ids[ca]
        if len(ask) > 1:
            answer[(ask[1][1], ask[1][2])] = ids[cb]
        if not dropped[sd]:
            chain = np.concatenate([[side_ends[sd, 0]], ids, [side_ends[sd, 1]]])
            roads.edges(chain[:-1], chain[1:], int(side_cls[sd]), int(side_setting[sd]), side=sd)

    # the local streets of every block
    line_base = 0
    for i in range(nb):
        for j in range(nb):
            bl = blocks[i][j]
            nx, ny = bl.xs.size, bl.ys.size
            if nx == 0 and ny == 0:
                continue
            k = i * nb + j
            grid = np.full((nx + 2, ny + 2), -1, dtype=np.int64)
            grid[0, 0], grid[-1, 0], grid[0, -1], grid[-1, -1] = (
                jid[i, j],
                jid[i + 1, j],
                jid[i, j + 1],
                jid[i + 1, j + 1],
            )
            if nx:
                grid[1:-1, 0][bl.vkeep[:, 0]] = answer[(k, 0)]
                grid[1:-1, -1][bl.vkeep[:, -1]] = answer[(k, 1)]
            if ny:
                grid[0, 1:-1][bl.hkeep[:, 0]] = answer[(k, 2)]
                grid[-1, 1:-1][bl.hkeep[:, -1]] = answer[(k, 3)]
            if nx and ny:
                used = bl.hkeep[:, :-1].T | bl.hkeep[:, 1:].T | bl.vkeep[:, :-1] | bl.vkeep[:, 1:]
                ua, ub = np.nonzero(used)
                if ua.size:
                    # jitter and winding relative to the usual gap between lines
                    gs = float(np.median(np.diff(np.concatenate([[0.0], bl.xs, [1.0]]))))
                    gt = float(np.median(np.diff(np.concatenate([[0.0], bl.ys, [1.0]]))))
                    jit = 0.12 if bl.setting == URBAN else 0.18
                    s = bl.xs[ua] + rng.normal(0.0, jit * gs, ua.size)
                    t = bl.ys[ub] + rng.normal(0.0, jit * gt, ua.size)
                    if bl.setting == SUBURBAN:  # winding streets
                        f, g = rng.uniform(0.8, 2.0, 2)
                        q = rng.uniform(0.0, 2 * np.pi, 2)
                        s = s + 0.35 * gs * np.sin(2 * np.pi * f * t + q[0])
                        t = t + 0.35 * gt * np.sin(2 * np.pi * g * s + q[1])
                    corners = np.array(
                        [pos[jid[i, j]], pos[jid[i + 1, j]], pos[jid[i, j + 1]], pos[jid[i + 1, j + 1]]]
                    )
                    x, y = _bilinear(corners, s.clip(0.01, 0.99), t.clip(0.01, 0.99))
                    grid[ua + 1, ub + 1] = roads.nodes(x, y)
            hb, ha = np.nonzero(bl.hkeep)
            roads.edges(grid[ha, hb + 1], grid[ha + 1, hb + 1], LOCAL, bl.setting, line_base + hb)
            line_base += ny
            va, vb = np.nonzero(bl.vkeep)
            roads.edges(grid[va + 1, vb], grid[va + 1, vb + 1], LOCAL, bl.setting, line_base + va)
            line_base += nx
    return side_cls


@dataclass
class _Pieces:
    """Undirected road pieces as flat arrays."""

    a: NDArray[np.int64]
    b: NDArray[np.int64]
    cls: NDArray[np.int64]
    setting: NDArray[np.int64]
    line: NDArray[np.int64]
    side: NDArray[np.int64]

    def take(self, sel: NDArray[np.int64] | NDArray[np.bool_]) -> _Pieces:
        return _Pieces(
            self.a[sel], self.b[sel], self.cls[sel], self.setting[sel], self.line[sel], self.side[sel]
        )

    @staticmethod
    def join(parts: list[_Pieces]) -> _Pieces:
        return _Pieces(
            *(
                np.concatenate([getattr(p, f) for p in parts])
                for f in ("a", "b", "cls", "setting", "line", "side")
            )
        )


def _cut_cul_de_sacs(
    rng: np.random.Generator, pcs: _Pieces, x: NDArray[np.float64], y: NDArray[np.float64], n: int
) -> tuple[_Pieces, NDArray[np.float64], NDArray[np.float64]]:
    """Some local streets blocked in the middle: each becomes two two-way cul-de-sacs."""
    p_cut = np.asarray(_CUT)[pcs.setting]
    cut = (pcs.cls == LOCAL) & (pcs.side < 0) & (rng.random(pcs.a.size) < p_cut)
    c = np.flatnonzero(cut)
    k = c.size
    ax, ay, bx, by = x[pcs.a[c]], y[pcs.a[c]], x[pcs.b[c]], y[pcs.b[c]]
    f = rng.uniform(0.3, 0.42, k)
    nx = np.concatenate([ax + f * (bx - ax), bx + f * (ax - bx)])
    ny = np.concatenate([ay + f * (by - ay), by + f * (ay - by)])
    m1 = np.arange(n, n + k, dtype=np.int64)
    m2 = m1 + k
    spur = pcs.take(np.concatenate([c, c]))
    spur.a = np.concatenate([pcs.a[c], pcs.b[c]])
    spur.b = np.concatenate([m1, m2])
    spur.line = np.full(2 * k, -1, dtype=np.int64)  # cul-de-sacs stay two-way
    return _Pieces.join([pcs.take(~cut), spur]), np.concatenate([x, nx]), np.concatenate([y, ny])


def _shape_nodes(
    rng: np.random.Generator, pcs: _Pieces, x: NDArray[np.float64], y: NDArray[np.float64]
) -> tuple[_Pieces, NDArray[np.float64], NDArray[np.float64]]:
    """Roads bend: long pieces get intermediate nodes of degree 2 off the straight line."""
    n = x.size
    dx, dy = x[pcs.b] - x[pcs.a], y[pcs.b] - y[pcs.a]
    chord = np.hypot(dx, dy)
    per = np.where(
        pcs.cls == LOCAL,
        np.asarray(_SHAPE_M)[pcs.setting],
        np.where(pcs.cls == COUNTRY, _COUNTRY_SHAPE_M, _ARTERIAL_SHAPE_M),
    )
    k = np.floor(chord / per + rng.random(chord.size)).astype(np.int64).clip(0, 12)
    bow = rng.normal(0.0, 1.0, chord.size) * np.where(pcs.cls == LOCAL, np.asarray(_BOW)[pcs.setting], 0.03)
    total = int(k.sum())
    owner = np.repeat(np.arange(chord.size), k)
    first = np.repeat(np.cumsum(k) - k, k)
    idx = np.arange(total) - first + 1  # 1..k within the piece
    kk = k[owner]
    t = (idx + rng.uniform(-0.25, 0.25, total)) / (kk + 1)
    off = bow[owner] * np.sin(np.pi * t) + rng.normal(0.0, 0.01, total)
    sx = x[pcs.a[owner]] + t * dx[owner] - off * dy[owner]
    sy = y[pcs.a[owner]] + t * dy[owner] + off * dx[owner]
    # piece e becomes k[e] + 1 pieces: a, s_1, ..., s_k, b
    m = k + 1
    e = np.repeat(np.arange(chord.size), m)
    j = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
    start = n + np.repeat(np.cumsum(k) - k, m)
    tail = np.where(j == 0, pcs.a[e], start + j - 1)
    head = np.where(j == k[e], pcs.b[e], start + j)
    out = pcs.take(e)
    out.a, out.b = tail, head
    return out, np.concatenate([x, sx]), np.concatenate([y, sy])


def _river_cut(
    lay: _Layout,
    rng: np.random.Generator,
    pcs: _Pieces,
    side_cls: NDArray[np.int64],
    x: NDArray[np.float64],
    y: NDArray[np.float64],
) -> tuple[_Pieces, NDArray[np.bool_]]:
    """Remove what lies in the river and every piece across it except on a few arterial bridges.

    Returns the remaining pieces and the nodes in the river (dropped unless on a bridge).
    """
    ry = lay.river_y(x)
    north = y > ry
    wet = np.abs(y - ry) < 0.5 * RIVER_WIDTH_M
    across = north[pcs.a] != north[pcs.b]
    # candidate bridges: arterial and country sides that cross the river
    cand = np.unique(pcs.side[across & (pcs.side >= 0)])
    cand = cand[side_cls[cand] != LOCAL]
    n_bridges = max(3, round(6 * np.sqrt(lay.side / SIDE_M)))
    chosen: list[int] = []
    if cand.size:
        mid_x = np.array([x[pcs.a[across & (pcs.side == c)]].mean() for c in cand])
        weight = lay.urbanity(mid_x, lay.river_y(mid_x)) + 0.05
        order = np.argsort(-np.log(rng.random(cand.size)) / weight)  # weighted order without replacement
        sep = 2.2 * ARTERIAL_PITCH_M
        for o in order:
            if all(abs(mid_x[o] - mid_x[q]) > sep for q in chosen):
                chosen.append(int(o))
            if len(chosen) == n_bridges:
                break
    bridge_sides = cand[np.array(chosen, dtype=np.int64)]
    on_bridge = np.isin(pcs.side, bridge_sides)
    keep_node = ~wet
    keep_node[pcs.a[on_bridge]] = True
    keep_node[pcs.b[on_bridge]] = True
    keep = on_bridge | (~across & keep_node[pcs.a] & keep_node[pcs.b])
    return pcs.take(keep), wet & ~keep_node


def _motorway_line(
    px: NDArray[np.float64], py: NDArray[np.float64], closed: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Nodes of the two carriageways along an axis: A to the right of the axis's direction (it runs that
    way, traffic keeps right), B to the left (it runs the other way)."""
    if closed:
        tx = np.roll(px, -1) - np.roll(px, 1)
        ty = np.roll(py, -1) - np.roll(py, 1)
    else:
        tx, ty = np.gradient(px), np.gradient(py)
    norm = np.hypot(tx, ty)
    nx, ny = ty / norm, -tx / norm  # to the right of the direction of travel
    o = CARRIAGEWAY_OFFSET_M
    return px + o * nx, py + o * ny, px - o * nx, py - o * ny


def _motorways(
    lay: _Layout,
    rng: np.random.Generator,
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    pcs: _Pieces,
    alive: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.float64], _Pieces]:
    """A ring and radials, dual carriageways with junctions every 2-4 km to the nearest arterial.

    Returns the new nodes' coordinates (numbered on from ``x.size``) and their pieces (one-way, a -> b).
    """
    side = lay.side
    n0 = x.size
    cx, cy = lay.centres[0, 0], lay.centres[0, 1]
    # arterial nodes a ramp may join
    art = np.zeros(n0, dtype=bool)
    sel = (pcs.cls == ARTERIAL) | (pcs.cls == COUNTRY)
    art[pcs.a[sel]] = True
    art[pcs.b[sel]] = True
    art &= alive
    art_idx = np.flatnonzero(art)
    tree = cKDTree(np.column_stack([x[art_idx], y[art_idx]]))
    north_of = y > lay.river_y(x)

    axes: list[tuple[NDArray[np.float64], NDArray[np.float64], bool]] = []
    radius = 0.31 * side
    n_ring = max(24, round(2 * np.pi * radius / MOTORWAY_STEP_M))
    th = np.linspace(0.0, 2 * np.pi, n_ring, endpoint=False)
    q = rng.uniform(0.0, 2 * np.pi, 2)
    r = radius * (1.0 + 0.05 * np.sin(2 * th + q[0]) + 0.03 * np.sin(3 * th + q[1]))
    axes.append((cx + r * np.cos(th), cy + r * np.sin(th), True))
    margin = 300.0
    for deg in _RADIAL_DEG:
        a = np.radians(deg + rng.normal(0.0, 6.0))
        d = np.array([np.cos(a), np.sin(a)])
        # from 7 % of the side out from the main centre to the edge of the square
        lims = []
        for k, c in ((0, cx), (1, cy)):
            if d[k] > 1e-9:
                lims.append((side - margin - c) / d[k])
            elif d[k] < -1e-9:
                lims.append((margin - c) / d[k])
        rho1, rho0 = min(lims), 0.07 * side
        n_r = max(4, round((rho1 - rho0) / MOTORWAY_STEP_M) + 1)
        lam = np.linspace(0.0, 1.0, n_r)
        rho = rho0 + lam * (rho1 - rho0)
        bend = rng.normal(0.0, 0.02 * side) * np.sin(np.pi * lam)
        axes.append((cx + rho * d[0] - bend * d[1], cy + rho * d[1] + bend * d[0], False))

    xs_new: list[NDArray[np.float64]] = []
    ys_new: list[NDArray[np.float64]] = []
    parts: list[_Pieces] = []
    nxt = n0
    carriage: list[tuple[NDArray[np.int64], NDArray[np.int64]]] = []

    def one_way(a: NDArray[np.int64], b: NDArray[np.int64], cls: int) -> None:
        k = a.size
        parts.append(
            _Pieces(
                a,
                b,
                np.full(k, cls, dtype=np.int64),
                np.full(k, RURAL, dtype=np.int64),
                np.full(k, -1, dtype=np.int64),
                np.full(k, -1, dtype=np.int64),
            )
        )

    for px, py, closed in axes:
        ax_, ay_, bx_, by_ = _motorway_line(px, py, closed)
        m = px.size
        ida = np.arange(nxt, nxt + m, dtype=np.int64)
        idb = ida + m
        nxt += 2 * m
        xs_new += [ax_, bx_]
        ys_new += [ay_, by_]
        nxt_i = np.roll(np.arange(m), -1) if closed else np.arange(1, m)
        cur_i = np.arange(m) if closed else np.arange(m - 1)
        one_way(ida[cur_i], ida[nxt_i], MOTORWAY)  # A runs forward
        one_way(idb[nxt_i], idb[cur_i], MOTORWAY)  # B runs backward
        carriage.append((ida, idb))

    # interchanges where each radial crosses the ring: both carriageways joined both ways
    ring_x, ring_y = axes[0][0], axes[0][1]
    ring_a, ring_b = carriage[0]
    avoid: list[tuple[int, int]] = []
    for k in range(1, len(axes)):
        px, py, _ = axes[k]
        d2 = (px[:, None] - ring_x[None, :]) ** 2 + (py[:, None] - ring_y[None, :]) ** 2
        qi, ri = np.unravel_index(int(np.argmin(d2)), d2.shape)
        ra, rb = carriage[k]
        for u_ in (ra[qi], rb[qi]):
            for v_ in (ring_a[ri], ring_b[ri]):
                one_way(np.array([u_, v_]), np.array([v_, u_]), RAMP)
        avoid += [(0, int(ri)), (k, int(qi))]

    # junctions to the arterial mesh
    mx, my = np.concatenate(xs_new), np.concatenate(ys_new)
    for k, (px, py, closed) in enumerate(axes):
        m = px.size
        ida, idb = carriage[k]
        step = np.hypot(np.diff(px), np.diff(py))
        arc = np.concatenate([[0.0], np.cumsum(step)])
        spots: list[int] = [] if closed else [0, m - 1]
        s = rng.uniform(1_000.0, 2_500.0)
        while s < arc[-1] - 1_000.0:
            spots.append(int(np.searchsorted(arc, s)))
            s += rng.uniform(2_000.0, 4_000.0)
        for p in spots:
            if any(kk == k and abs(p - pp) * MOTORWAY_STEP_M < 1_500.0 for kk, pp in avoid):
                continue
            if abs(py[p] - lay.river_y(np.array([px[p]]))[0]) < 800.0:
                continue
            dist, near = tree.query([px[p], py[p]], k=8)
            hit = [
                int(art_idx[c])
                for dd, c in zip(dist, near, strict=True)
                if dd < 1_500.0 and north_of[art_idx[c]] == (py[p] > lay.river_y(np.array([px[p]]))[0])
            ]
            if not hit:
                continue
            node = hit[0]
            if not closed and p in (0, m - 1):  # the ends: A starts at 0 and ends at m - 1, B the reverse
                start, end = (ida[0], idb[0]) if p == 0 else (idb[m - 1], ida[m - 1])
                one_way(np.array([node, end]), np.array([start, node]), RAMP)
            else:
                # off A before the junction, on A after it; B runs the other way
                before, after = ida[(p - 1) % m], ida[(p + 1) % m]
                one_way(np.array([before, node]), np.array([node, after]), RAMP)
                before, after = idb[(p + 1) % m], idb[(p - 1) % m]
                one_way(np.array([before, node]), np.array([node, after]), RAMP)
    return mx, my, _Pieces.join(parts)


def _to_lonlat(
    x: NDArray[np.float64], y: NDArray[np.float64], side: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The city's plane on the sphere: sinusoidal about the middle of the square (lengths kept along
    parallels and meridians)."""
    lon0, lat0 = CENTRE_LONLAT
    lat = lat0 + np.degrees((y - 0.5 * side) / EARTH_RADIUS_M)
    lon = lon0 + np.degrees((x - 0.5 * side) / (EARTH_RADIUS_M * np.cos(np.radians(lat))))
    return lon, lat


def metro_city(seed: int = SEED, scale: float = 1.0) -> City:
    """The generated metropolitan city (see the module docstring), its largest strongly connected part.

    Parameters
    ----------
    seed : int
        Everything random comes from this seed: the same seed gives the same city.
    scale : float
        Shrinks the square's side (70 km at 1.0) and the layout with it (centres, river, motorways); block
        sizes and the arterial spacing stay, so nodes grow with ``scale ** 2`` (~0.2 gives ~10,000 nodes).

    Returns
    -------
    City
        Named ``metro250k``, timezone Asia/Shanghai, source ``generated``.
    """
    lay = _layout(seed, scale)
    rng = np.random.default_rng([seed, 2])
    roads = _Roads()
    side_cls = _streets(lay, rng, roads)
    x, y = np.concatenate(roads.x), np.concatenate(roads.y)
    pcs = _Pieces(*(np.concatenate(getattr(roads, f)) for f in ("a", "b", "cls", "setting", "line", "side")))
    pcs, x, y = _cut_cul_de_sacs(rng, pcs, x, y, x.size)
    pcs, x, y = _shape_nodes(rng, pcs, x, y)
    pcs, drowned = _river_cut(lay, rng, pcs, side_cls, x, y)
    mx, my, mp = _motorways(lay, rng, x, y, pcs, ~drowned)

    # one-way local lines, in a random direction each; never into a dead end
    n_local = x.size
    # nothing outside the square (bows and bends on its edges)
    x, y = np.concatenate([x, mx]).clip(0.0, lay.side), np.concatenate([y, my]).clip(0.0, lay.side)
    deg = np.bincount(pcs.a, minlength=n_local) + np.bincount(pcs.b, minlength=n_local)
    n_lines = int(pcs.line.max()) + 1 if pcs.line.size else 0
    lines_one_way = rng.random(n_lines)
    lines_flip = rng.random(n_lines) < 0.5
    has_line = pcs.line >= 0
    lid = np.where(has_line, pcs.line, 0)
    one_way = has_line & (lines_one_way[lid] < np.asarray(_ONE_WAY)[pcs.setting])
    one_way &= (deg[pcs.a] > 1) & (deg[pcs.b] > 1)
    flip = has_line & lines_flip[lid]
    tail = np.where(flip, pcs.b, pcs.a)
    head = np.where(flip, pcs.a, pcs.b)

    u = np.concatenate([tail, head[~one_way], mp.a])
    v = np.concatenate([head, tail[~one_way], mp.b])
    cls = np.concatenate([pcs.cls, pcs.cls[~one_way], mp.cls])
    lon, lat = _to_lonlat(x, y, lay.side)
    bend = np.where(cls >= MOTORWAY, 0.02, 0.3) * rng.random(u.size) ** 2
    length = haversine_m(lon[u], lat[u], lon[v], lat[v]) * (1.0 + bend)
    ids = np.arange(x.size, dtype=np.int64)
    network = largest_strongly_connected(build_network(ids, lon, lat, u, v, length, SPEED_KMH[cls], 30.0))
    return city_from_network(
        network, CityMeta(name="metro250k", timezone="Asia/Shanghai", source="generated")
    )


def river(seed: int = SEED, scale: float = 1.0) -> NDArray[np.float64]:
    """The river's centre line of ``metro_city(seed, scale)`` as lon/lat, west to east.

    Returns
    -------
    float64 (k, 2)
        Points about 50 m apart (times ``scale``), the first on the west edge and the last on the east edge.
    """
    lay = _layout(seed, scale)
    xs = np.linspace(0.0, lay.side, 1401)
    lon, lat = _to_lonlat(xs, lay.river_y(xs), lay.side)
    return np.column_stack([lon, lat])


def river_crossings(city: City, seed: int = SEED, scale: float = 1.0) -> NDArray[np.float64]:
    """Where the city's roads cross the river: one projected x/y (metres) per place.

    Directed edges with ends on the two banks are the crossing edges; those within 300 m of each other
    (a dual carriageway, the two directions of a bridge) make one place.

    Returns
    -------
    float64 (k, 2)
        The crossing places' midpoints, sorted west to east.
    """
    net = city.network
    rl = river(seed, scale)
    rx, ry = net.project(rl[:, 0], rl[:, 1])
    north = net.y_m > np.interp(net.x_m, rx, ry)
    e = np.flatnonzero(north[net.edge_u] != north[net.edge_v])
    if e.size == 0:
        return np.zeros((0, 2))
    mid = 0.5 * np.column_stack(
        [net.x_m[net.edge_u[e]] + net.x_m[net.edge_v[e]], net.y_m[net.edge_u[e]] + net.y_m[net.edge_v[e]]]
    )
    pairs = cKDTree(mid).query_pairs(300.0, output_type="ndarray")
    adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(e.size, e.size))
    _, label = connected_components(adj, directed=False)
    places = np.column_stack(
        [
            np.bincount(label, mid[:, 0]) / np.bincount(label),
            np.bincount(label, mid[:, 1]) / np.bincount(label),
        ]
    )
    return places[np.argsort(places[:, 0])]


def _half_side(city: City) -> float:
    """Half the side of the square a ``metro_city`` was generated on: its nodes' farthest reach from the
    middle of the square in the generator's plane (junctions lie on the square's edges)."""
    lon0, lat0 = CENTRE_LONLAT
    net = city.network
    dy = EARTH_RADIUS_M * np.radians(net.lat - lat0)
    dx = EARTH_RADIUS_M * np.cos(np.radians(net.lat)) * np.radians(net.lon - lon0)
    return float(max(np.abs(dx).max(), np.abs(dy).max()))


def centre_layout(city: City) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The centres' projected x/y (k, 2) and their weights (k,) summing to 1."""
    side = 2.0 * _half_side(city)
    lon, lat = _to_lonlat(_CENTRES[:, 0] * side, _CENTRES[:, 1] * side, side)
    x, y = city.network.project(lon, lat)
    mass = _CENTRES[:, 2] * _CENTRES[:, 3] ** 2
    return np.column_stack([x, y]), mass / mass.sum()


def centres(city: City) -> NDArray[np.float64]:
    """The dense urban centres of a city made by :func:`metro_city` (the same layout for every seed).

    Returns
    -------
    float64 (5, 2)
        Projected x/y in metres (``city.network.x_m``/``y_m``), the main centre first.
    """
    return centre_layout(city)[0]


def near_centres(
    city: City, rng: np.random.Generator, n: int, spread_m: float = 2_500.0
) -> NDArray[np.int64]:
    """``n`` node indices drawn around the centres (riders, taxis and POIs where the city is dense).

    Each draw picks a centre with probability proportional to its weight times its radius squared (the
    main centre about 43 %), moves from it by a normal offset of standard deviation ``spread_m`` on each
    axis, and snaps to the nearest node: :class:`bench.load.Centres` on :func:`centre_layout`, which the
    epoch benchmark keeps to draw from many times.

    Parameters
    ----------
    city : City
        A city made by :func:`metro_city`.
    rng : numpy Generator
    n : int
        How many (repeats possible).
    spread_m : float
        Standard deviation of the offset on each axis; 2.5 km suits the full city, shrink it with ``scale``.

    Returns
    -------
    int64 (n,)
    """
    pos, weight = centre_layout(city)
    return Centres(city, pos, weight, spread_m)(rng, n)


def describe(city: City) -> dict[str, float]:
    """Counts of a city's network: nodes, edges, extent, edges per road class (by speed), one-way edges
    (no reverse edge) and the share of local streets that are one-way, dead ends (one neighbour), the
    nodes with two, three and four or more neighbours, and nodes per km2 of the extent."""
    net = city.network
    n = net.n_nodes
    kmh = np.round(net.edge_length_m / net.edge_time_s * 3.6)
    u, v = net.edge_u.astype(np.int64), net.edge_v.astype(np.int64)
    key = u * n + v
    rev = v * n + u
    has_rev = np.isin(rev, key)
    lo, hi = np.minimum(u, v), np.maximum(u, v)
    und = np.unique(lo * n + hi)
    nbrs = np.bincount(und // n, minlength=n) + np.bincount(und % n, minlength=n)
    out: dict[str, float] = {
        "nodes": n,
        "edges": net.n_edges,
        "edges_per_node": net.n_edges / n,
        "width_km": (float(net.x_m.max()) - float(net.x_m.min())) / 1000.0,
        "height_km": (float(net.y_m.max()) - float(net.y_m.min())) / 1000.0,
        "one_way_edges": int((~has_rev).sum()),
        "dead_ends": int((nbrs == 1).sum()),
        "degree2_share": float((nbrs == 2).mean()),
        "degree3_share": float((nbrs == 3).mean()),
        "degree4plus_share": float((nbrs >= 4).mean()),
    }
    for name, cls in (("motorway", MOTORWAY), ("ramp", RAMP), ("country", COUNTRY), ("arterial", ARTERIAL)):
        out[f"{name}_edges"] = int((kmh == SPEED_KMH[cls]).sum())
    local = kmh == SPEED_KMH[LOCAL]
    out["local_edges"] = int(local.sum())
    local_one_way = int((local & ~has_rev).sum())  # a two-way street is two edges, a one-way street one
    out["local_one_way_share"] = local_one_way / max(
        1, local_one_way + (int(local.sum()) - local_one_way) // 2
    )
    out["nodes_per_km2"] = n / max(out["width_km"] * out["height_km"], 1e-9)
    return out


def shuffled(city: City, seed: int) -> tuple[City, NDArray[np.int64]]:
    """``city``'s network with its nodes in a random order (the same nodes, ids and edges), as a city; and
    each node's index in it."""
    net = city.network
    order = np.random.default_rng(seed).permutation(net.n_nodes)
    index = np.empty(net.n_nodes, dtype=np.int64)
    index[order] = np.arange(net.n_nodes, dtype=np.int64)
    ids = net.node_ids
    speed_kmh = net.edge_length_m / net.edge_time_s * 3.6
    out = build_network(
        ids[order],
        net.lon[order],
        net.lat[order],
        ids[net.edge_u],
        ids[net.edge_v],
        net.edge_length_m,
        speed_kmh,
    )
    meta = CityMeta(name=f"{city.name}-shuffled", timezone=city.horizon.timezone, source=city.source)
    return city_from_network(out, meta), index


def main(argv: list[str] | None = None) -> int:
    """Build the city, print its counts and the build time."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--scale", type=float, default=1.0)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    city = metro_city(args.seed, args.scale)
    took = time.perf_counter() - t0
    stats = describe(city)
    stats["bridges"] = len(river_crossings(city, args.seed, args.scale))
    stats["centres"] = len(centres(city))
    stats["build_s"] = took
    stats["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    for k, val in stats.items():
        print(f"{k:>18}: {val:,.3f}" if isinstance(val, float) else f"{k:>18}: {val:,}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
