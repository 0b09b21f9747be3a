"""The road network and its shortest paths (paper Section 3, docs/METHOD.md sections 1-2).

* ``network``: :class:`Network` (CSR arrays, projection, snapping), built from edge lists.
* ``graph``: :class:`RoadGraph`, the edges and the forward and reverse search graphs; costs (fixed,
  kappa-weighted, and the lazy metric of Algorithm 1's discounted trees).
* ``contraction``: degree-2 chains contracted into super-edges.
* ``heaps``: a search's workspace and its heap and bucket queues.
* ``dijkstra``: the one Dijkstra (``run``, ``grow``).
* ``astar``: the guided (A*) search toward one target.
* ``unfolding``: results read off a search (resolve, unfold, labels, paths) and the batch searches.
* ``point_to_point``: fastest paths between pairs with the landmark bounds; the landmarks; the crossing
  time.
* ``hierarchy``: fastest paths between pairs through a contraction hierarchy (``shortcuts`` builds it).
* ``scratch``: per-thread search scratch (``Scratch``) lent by a pool (``ScratchPool``).
"""

from services.network import astar, dijkstra, heaps, point_to_point, unfolding
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
from services.network.point_to_point import crossing_us, fastest_path, landmark_fastest_paths, landmarks
from services.network.scratch import Scratch, ScratchPool, scratch_pool

__all__ = [
    "heaps",
    "dijkstra",
    "astar",
    "unfolding",
    "point_to_point",
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
    "landmark_fastest_paths",
    "landmarks",
    "crossing_us",
    "Scratch",
    "ScratchPool",
    "scratch_pool",
]
