"""Road network as flat arrays: nodes with lon/lat and projected metres, directed edges in CSR order.

Field names here are the contract the importers, the bundles and the searches share.

Build a network with :func:`build_network` (external ids in, indices out) and keep its largest strongly
connected component with :func:`largest_strongly_connected`. Positions given as lon/lat snap to the nearest
node in the projected plane (docs/METHOD.md section 2): :meth:`Network.snap`, :meth:`Network.snap_many`.
"""

from __future__ import annotations

import operator
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from pyproj import Transformer
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = [
    "Network",
    "SnapError",
    "build_network",
    "largest_strongly_connected",
    "lonlat_of",
    "utm_crs",
]


class SnapError(ValueError):
    """A lon/lat lies farther than the snapping limit from every node (or the node id is unknown)."""


# pyproj transformers are not safe to share between threads; the API snaps in a thread pool.
_local = threading.local()


def _transformer(crs: str, inverse: bool = False) -> Transformer:
    """WGS84 -> ``crs`` (or ``crs`` -> WGS84 when ``inverse``), lon/lat order, one per thread."""
    cache: dict[tuple[str, bool], Transformer] | None = getattr(_local, "transformers", None)
    if cache is None:
        cache = {}
        _local.transformers = cache
    tr = cache.get((crs, inverse))
    if tr is None:
        src, dst = (crs, "EPSG:4326") if inverse else ("EPSG:4326", crs)
        tr = Transformer.from_crs(src, dst, always_xy=True)
        cache[(crs, inverse)] = tr
    return tr


def lonlat_of(crs: str, x_m: ArrayLike, y_m: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """WGS84 lon/lat of points given in projected metres of ``crs`` (the inverse of ``Network.project``).

    Parameters
    ----------
    crs : str
        The projection, e.g. a network's or grid's ``crs``.
    x_m, y_m : float arrays of one shape

    Returns
    -------
    lon, lat : float64 arrays of that shape
    """
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError("x_m and y_m must have the same shape")
    lon, lat = _transformer(crs, inverse=True).transform(x, y)
    return np.asarray(lon, dtype=np.float64).reshape(x.shape), np.asarray(lat, dtype=np.float64).reshape(
        x.shape
    )


def utm_crs(lon: float, lat: float) -> str:
    """The UTM zone containing a WGS84 point, as an EPSG code string.

    Parameters
    ----------
    lon, lat : float
        WGS84 degrees.

    Returns
    -------
    str
        ``"EPSG:326zz"`` north of the equator, ``"EPSG:327zz"`` south of it (``zz`` the zone, 01-60).
    """
    if not (np.isfinite(lon) and np.isfinite(lat) and -180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):
        raise ValueError(f"not a WGS84 position: lon={lon}, lat={lat}")
    zone = int(np.floor((lon + 180.0) / 6.0)) % 60 + 1
    return f"EPSG:{32600 + zone if lat >= 0.0 else 32700 + zone}"


@dataclass(frozen=True, slots=True, eq=False)
class Network:
    """A directed road network.

    Attributes
    ----------
    node_ids : int64 (n,)      external node ids (OSM ids or user ids), unique
    lon, lat : float64 (n,)    WGS84 degrees
    x_m, y_m : float64 (n,)    projected metres in ``crs``
    crs : str                  e.g. "EPSG:32648" (UTM zone of the network's centroid)
    edge_u, edge_v : int32 (m,)  node *indices*; edges sorted by (u, v); no self-loops, no parallel edges
    edge_length_m : float64 (m,)
    edge_time_s : float64 (m,)   length / speed
    indptr : int64 (n+1,)      CSR row pointer: out-edges of node i are edges indptr[i]:indptr[i+1]

    Notes
    -----
    The id → index map, the KD-tree and the sorted edge keys are built on first use and cached in the
    private fields (the arrays themselves are never modified). Building them twice in two threads is
    harmless: both build the same thing.
    """

    node_ids: NDArray[np.int64]
    lon: NDArray[np.float64]
    lat: NDArray[np.float64]
    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    crs: str
    edge_u: NDArray[np.int32]
    edge_v: NDArray[np.int32]
    edge_length_m: NDArray[np.float64]
    edge_time_s: NDArray[np.float64]
    indptr: NDArray[np.int64]
    _index: dict[int, int] = field(default_factory=dict, repr=False)
    _tree: object = field(default=None, repr=False)
    _edge_key: object = field(default=None, repr=False)

    @property
    def n_nodes(self) -> int:
        return int(self.node_ids.shape[0])

    @property
    def n_edges(self) -> int:
        return int(self.edge_u.shape[0])

    def csr(self, weights: NDArray[np.float64]) -> sp.csr_matrix:
        """Sparse adjacency matrix with the given per-edge weights (edge order = CSR order)."""
        return sp.csr_matrix(
            (weights, self.edge_v.astype(np.int32), self.indptr), shape=(self.n_nodes, self.n_nodes)
        )

    # ------------------------------------------------------------------ ids

    def index_of(self, node_id: int | np.integer[Any]) -> int:
        """Index of the node with external id ``node_id``.

        Raises
        ------
        SnapError
            If no node has that id.
        """
        index = self._index
        if not index and self.n_nodes:
            index.update(zip(self.node_ids.tolist(), range(self.n_nodes), strict=True))
        try:
            return index[operator.index(node_id)]  # an int or numpy integer; never a float truncated
        except (KeyError, TypeError):
            raise SnapError(f"unknown node id {node_id!r}") from None

    # ----------------------------------------------------------- projection

    def project(self, lon: ArrayLike, lat: ArrayLike) -> tuple[Any, Any]:
        """Project WGS84 lon/lat (scalars or arrays) to metres in ``crs``.

        Returns
        -------
        x, y
            Floats for scalar input, float64 arrays otherwise.
        """
        x, y = _transformer(self.crs).transform(lon, lat)
        if np.ndim(lon) == 0 and np.ndim(lat) == 0:
            return float(x), float(y)
        return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)

    def _kdtree(self) -> cKDTree:
        tree = self._tree
        if tree is None:
            tree = cKDTree(np.column_stack([self.x_m, self.y_m]))
            object.__setattr__(self, "_tree", tree)
        assert isinstance(tree, cKDTree)
        return tree

    def snap(self, lon: float, lat: float, limit_m: float) -> tuple[int, float]:
        """The node nearest to a lon/lat in the projected plane (docs/METHOD.md section 2).

        Parameters
        ----------
        lon, lat : float
            WGS84 degrees.
        limit_m : float
            Largest accepted distance to the nearest node.

        Returns
        -------
        (int, float)
            Node index and its distance in metres.

        Raises
        ------
        SnapError
            If the position is not a finite WGS84 position or lies farther than ``limit_m`` from every node.
        """
        nodes, dists = self.snap_many(
            np.array([lon], dtype=np.float64), np.array([lat], dtype=np.float64), limit_m
        )
        return int(nodes[0]), float(dists[0])

    def snap_many(
        self, lon: ArrayLike, lat: ArrayLike, limit_m: float
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Vectorized :meth:`snap`.

        Returns
        -------
        nodes : int64 (k,)
        dist_m : float64 (k,)

        Raises
        ------
        SnapError
            Naming the first offending position (its position in the input, the distance and the limit).
        """
        lon_a = np.atleast_1d(np.asarray(lon, dtype=np.float64))
        lat_a = np.atleast_1d(np.asarray(lat, dtype=np.float64))
        if lon_a.shape != lat_a.shape or lon_a.ndim != 1:
            raise ValueError("lon and lat must be 1-d arrays of the same length")
        if self.n_nodes == 0:
            raise SnapError("the network has no nodes")
        bad = ~(np.isfinite(lon_a) & np.isfinite(lat_a) & (np.abs(lon_a) <= 180.0) & (np.abs(lat_a) <= 90.0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise SnapError(f"position {i} is not a WGS84 lon/lat: ({lon_a[i]}, {lat_a[i]})")
        if lon_a.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64)
        x, y = self.project(lon_a, lat_a)
        dist, nodes = self._kdtree().query(np.column_stack([x, y]))
        dist = np.asarray(dist, dtype=np.float64)
        far = ~(dist <= limit_m)
        if far.any():
            i = int(np.flatnonzero(far)[0])
            raise SnapError(
                f"position {i} ({lon_a[i]:.6f}, {lat_a[i]:.6f}) is {dist[i]:.0f} m from the nearest node "
                f"(limit {limit_m:.0f} m)"
            )
        return np.asarray(nodes, dtype=np.int64), dist

    # ---------------------------------------------------------------- edges

    def _keys(self) -> NDArray[np.int64]:
        keys = self._edge_key
        if keys is None:
            keys = self.edge_u.astype(np.int64) * self.n_nodes + self.edge_v.astype(np.int64)
            object.__setattr__(self, "_edge_key", keys)
        assert isinstance(keys, np.ndarray)
        return keys

    def edge_ids(self, path_nodes: ArrayLike) -> NDArray[np.int64]:
        """Edge indices joining consecutive nodes of a path.

        Parameters
        ----------
        path_nodes : int array (k,)
            Node indices; fewer than two nodes give an empty result.

        Returns
        -------
        int64 (k-1,)
            ``e[i]`` is the edge from ``path_nodes[i]`` to ``path_nodes[i+1]``.

        Raises
        ------
        ValueError
            If a node index is out of range or a consecutive pair is not an edge.
        """
        p = np.asarray(path_nodes, dtype=np.int64).ravel()
        if p.size < 2:
            return np.zeros(0, dtype=np.int64)
        if p.min() < 0 or p.max() >= self.n_nodes:
            raise ValueError("path node index out of range")
        want = p[:-1] * self.n_nodes + p[1:]
        keys = self._keys()
        pos = np.searchsorted(keys, want)
        found = pos < keys.size
        found[found] = keys[pos[found]] == want[found]
        if not found.all():
            i = int(np.flatnonzero(~found)[0])
            raise ValueError(f"no edge from node {int(p[i])} to node {int(p[i + 1])} (path position {i})")
        return pos.astype(np.int64)

    def bbox(self) -> tuple[float, float, float, float]:
        """``(min_lon, min_lat, max_lon, max_lat)`` of the nodes."""
        if self.n_nodes == 0:
            raise ValueError("the network has no nodes")
        return (float(self.lon.min()), float(self.lat.min()), float(self.lon.max()), float(self.lat.max()))


def _as_1d(name: str, values: ArrayLike, dtype: type) -> NDArray[Any]:
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional")
    if dtype is np.int64:
        if arr.size and not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{name} must hold integers")
        return arr.astype(np.int64)
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


def _checked_nodes(
    node_ids: ArrayLike | Sequence[int], lon: ArrayLike, lat: ArrayLike
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
    """The nodes' ids, lon and lat as arrays, checked, and the order that sorts the ids (``ids[order]`` is
    ascending)."""
    ids = _as_1d("node_ids", node_ids, np.int64)
    lon_a = _as_1d("lon", lon, np.float64)
    lat_a = _as_1d("lat", lat, np.float64)
    n = ids.size
    if n == 0:
        raise ValueError("a network needs at least one node")
    if lon_a.size != n or lat_a.size != n:
        raise ValueError("node_ids, lon and lat must have the same length")
    if (np.abs(lon_a) > 180.0).any() or (np.abs(lat_a) > 90.0).any():
        raise ValueError("lon must lie in [-180, 180] and lat in [-90, 90]")
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    if n > 1 and (sorted_ids[1:] == sorted_ids[:-1]).any():
        dup = int(sorted_ids[1:][sorted_ids[1:] == sorted_ids[:-1]][0])
        raise ValueError(f"duplicate node id {dup}")
    return ids, lon_a, lat_a, order


_Edges = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]
"""Edges as arrays: tails, heads, lengths in metres, speeds in km/h."""


def _checked_edges(
    edge_u_ids: ArrayLike | Sequence[int],
    edge_v_ids: ArrayLike | Sequence[int],
    length_m: ArrayLike,
    speed_kmh: ArrayLike | None,
    default_speed_kmh: float,
) -> _Edges:
    """The edges' tail and head ids, lengths and speeds (the default where there is none) as arrays,
    checked."""
    eu = _as_1d("edge_u_ids", edge_u_ids, np.int64)
    ev = _as_1d("edge_v_ids", edge_v_ids, np.int64)
    length = _as_1d("length_m", length_m, np.float64)
    m = eu.size
    if ev.size != m or length.size != m:
        raise ValueError("edge_u_ids, edge_v_ids and length_m must have the same length")
    if (length < 0).any():
        raise ValueError("edge lengths must be non-negative")
    if not (np.isfinite(default_speed_kmh) and default_speed_kmh > 0):
        raise ValueError("default_speed_kmh must be positive")
    if speed_kmh is None:
        return eu, ev, length, np.full(m, float(default_speed_kmh))
    speed = np.asarray(speed_kmh, dtype=np.float64).ravel()
    if speed.size != m:
        raise ValueError("speed_kmh must have one entry per edge")
    speed = np.where(np.isnan(speed), float(default_speed_kmh), speed)
    if not (np.isfinite(speed) & (speed > 0)).all():
        raise ValueError("edge speeds must be positive and finite")
    return eu, ev, length, speed


def _node_index(
    ext: NDArray[np.int64], sorted_ids: NDArray[np.int64], order: NDArray[np.intp], what: str
) -> NDArray[np.int64]:
    """The node index of every external id in ``ext``, given the ids in ascending order and the order that
    sorts them; ``what`` names ``ext`` in the error for an unknown id."""
    pos = np.searchsorted(sorted_ids, ext)
    ok = pos < sorted_ids.size
    ok[ok] = sorted_ids[pos[ok]] == ext[ok]
    if not ok.all():
        raise ValueError(f"{what} names unknown node id {int(ext[~ok][0])}")
    return order[pos].astype(np.int64)


def _simple_edges(
    u: NDArray[np.int64], v: NDArray[np.int64], length: NDArray[np.float64], speed: NDArray[np.float64]
) -> _Edges:
    """The edges ``(u, v, length, speed)`` without self-loops, the shortest of parallel ones kept, sorted
    by (u, v)."""
    keep = u != v
    u, v, length, speed = u[keep], v[keep], length[keep], speed[keep]
    # sort by (u, v, length): the first of each (u, v) run is the shortest parallel edge
    srt = np.lexsort((length, v, u))
    u, v, length, speed = u[srt], v[srt], length[srt], speed[srt]
    if u.size:
        first = np.ones(u.size, dtype=bool)
        first[1:] = (u[1:] != u[:-1]) | (v[1:] != v[:-1])
        u, v, length, speed = u[first], v[first], length[first], speed[first]
    return u, v, length, speed


def build_network(
    node_ids: ArrayLike | Sequence[int],
    lon: ArrayLike,
    lat: ArrayLike,
    edge_u_ids: ArrayLike | Sequence[int],
    edge_v_ids: ArrayLike | Sequence[int],
    length_m: ArrayLike,
    speed_kmh: ArrayLike | None = None,
    default_speed_kmh: float = 35.0,
    crs: str | None = None,
) -> Network:
    """Build a :class:`Network` from external node ids and directed edges between them.

    Self-loops are dropped; of parallel edges the shortest is kept (its speed with it); edges are sorted
    by (u, v). Travel time is ``length_m / (speed_kmh / 3.6)`` (docs/METHOD.md section 2).

    Parameters
    ----------
    node_ids : int (n,)
        Unique external ids; node ``i`` of the result is ``node_ids[i]``.
    lon, lat : float (n,)
        WGS84 degrees.
    edge_u_ids, edge_v_ids : int (m,)
        External ids of each edge's tail and head.
    length_m : float (m,)
        Non-negative edge lengths.
    speed_kmh : float (m,), optional
        Per-edge speeds; NaN entries take ``default_speed_kmh``.
    default_speed_kmh : float
        Speed of edges without one (35 km/h, docs/METHOD.md section 10).
    crs : str, optional
        Projected CRS; by default the UTM zone of the nodes' mean lon/lat.

    Returns
    -------
    Network

    Raises
    ------
    ValueError
        On mismatched lengths, duplicate ids, non-finite or out-of-range coordinates, negative lengths,
        non-positive speeds or edges naming an unknown node.
    """
    ids, lon_a, lat_a, order = _checked_nodes(node_ids, lon, lat)
    eu, ev, length, speed = _checked_edges(edge_u_ids, edge_v_ids, length_m, speed_kmh, default_speed_kmh)
    sorted_ids = ids[order]
    u = _node_index(eu, sorted_ids, order, "edge_u_ids")
    v = _node_index(ev, sorted_ids, order, "edge_v_ids")
    u, v, length, speed = _simple_edges(u, v, length, speed)
    n = ids.size
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(u, minlength=n), out=indptr[1:])

    if crs is None:
        crs = utm_crs(float(lon_a.mean()), float(lat_a.mean()))
    x, y = _transformer(crs).transform(lon_a, lat_a)
    return Network(
        node_ids=ids,
        lon=lon_a,
        lat=lat_a,
        x_m=np.asarray(x, dtype=np.float64),
        y_m=np.asarray(y, dtype=np.float64),
        crs=crs,
        edge_u=u.astype(np.int32),
        edge_v=v.astype(np.int32),
        edge_length_m=length,
        edge_time_s=length / (speed / 3.6),
        indptr=indptr,
    )


def largest_strongly_connected(network: Network) -> Network:
    """The largest strongly connected component of a network, as a network of its own.

    Node and edge order are kept (so edges stay sorted by (u, v)); the projection is unchanged. Of two
    equally large components the one holding the lowest node index wins.

    Parameters
    ----------
    network : Network

    Returns
    -------
    Network
        ``network`` itself when it is already strongly connected.
    """
    n = network.n_nodes
    if n == 0:
        return network
    adj = network.csr(np.ones(network.n_edges, dtype=np.float64))
    n_comp, labels = connected_components(adj, directed=True, connection="strong")
    if n_comp == 1:
        return network
    sizes = np.bincount(labels, minlength=n_comp)
    # of the largest components, the one holding the lowest node index
    best = labels[int(np.argmax(sizes[labels] == sizes.max()))]
    keep = labels == best
    new_index = np.full(n, -1, dtype=np.int64)
    new_index[keep] = np.arange(int(keep.sum()))
    ekeep = keep[network.edge_u] & keep[network.edge_v]
    u = new_index[network.edge_u[ekeep]]
    v = new_index[network.edge_v[ekeep]]
    n_new = int(keep.sum())
    indptr = np.zeros(n_new + 1, dtype=np.int64)
    np.cumsum(np.bincount(u, minlength=n_new), out=indptr[1:])
    return Network(
        node_ids=network.node_ids[keep],
        lon=network.lon[keep],
        lat=network.lat[keep],
        x_m=network.x_m[keep],
        y_m=network.y_m[keep],
        crs=network.crs,
        edge_u=u.astype(np.int32),
        edge_v=v.astype(np.int32),
        edge_length_m=network.edge_length_m[ekeep],
        edge_time_s=network.edge_time_s[ekeep],
        indptr=indptr,
    )
