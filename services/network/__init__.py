"""The road network and its shortest paths (paper Section 3, docs/METHOD.md sections 1-2).

* ``network``: :class:`Network` (CSR arrays, projection, snapping), built from edge lists.
* ``graph``: :class:`RoadGraph`, the edges and the forward and reverse search graphs; costs (fixed,
  kappa-weighted, and the lazy metric of Algorithm 1's discounted trees).
* ``contraction``: degree-2 chains contracted into super-edges.
* ``search``: the one Dijkstra, the guided (A*) search and its landmarks; canonical shortest paths.
* ``pads``: per-thread search scratch.
"""

from services.network import search
from services.network.contraction import Contraction, contract
from services.network.graph import (
    INF,
    TIE_BITS,
    US_PER_S,
    Costs,
    Edges,
    Lazy,
    RoadGraph,
    SearchGraph,
    fixed_super_edges,
    kappa_cost,
    lazy_edge,
    lazy_fill,
    no_lazy,
    prepare,
    prepare_into,
    road_graph,
    to_us,
)
from services.network.network import (
    Network,
    SnapError,
    build_network,
    largest_strongly_connected,
    lonlat_of,
    utm_crs,
)
from services.network.pads import Pad, Pads, pads_for
from services.network.search import crossing_us, fastest_path, fastest_paths, landmarks

__all__ = [
    "search",
    "Network",
    "SnapError",
    "build_network",
    "largest_strongly_connected",
    "lonlat_of",
    "utm_crs",
    "Edges",
    "SearchGraph",
    "Costs",
    "Lazy",
    "no_lazy",
    "kappa_cost",
    "lazy_edge",
    "lazy_fill",
    "fixed_super_edges",
    "prepare",
    "prepare_into",
    "RoadGraph",
    "road_graph",
    "INF",
    "TIE_BITS",
    "US_PER_S",
    "to_us",
    "Contraction",
    "contract",
    "fastest_path",
    "fastest_paths",
    "landmarks",
    "crossing_us",
    "Pad",
    "Pads",
    "pads_for",
]
