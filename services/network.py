"""Road network as flat arrays: nodes with lon/lat and projected metres, directed edges in CSR order.

Implementation owner: the cities work (see docs/DESIGN.md). Field names here are the contract.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

__all__ = ["Network", "SnapError"]


class SnapError(ValueError):
    """A lon/lat lies farther than the snapping limit from every node (or the node id is unknown)."""


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
