"""What every step of one decision epoch reads (docs/METHOD.md section 4)."""

from __future__ import annotations

from dataclasses import dataclass

from services.city import City
from services.model import CountsView
from services.network.graph import RoadGraph
from services.network.pads import Pads

__all__ = ["Epoch"]


@dataclass(frozen=True, slots=True)
class Epoch:
    """One epoch's shared inputs: the city and its search graph, the counts as of the epoch's start, the
    epoch's time and interval, the threads for the independent searches and their scratch pads.

    Attributes
    ----------
    city : the served city (network, grid, weights, parameters).
    graph : ``road_graph(city)``.
    counts : Lambda per interval and the (interval, cell) pairs each taxi is already counted in.
    now : the epoch's time (seconds); every path of the epoch departs then.
    k0 : the interval ``now`` falls in.
    workers : threads for the independent searches (no result depends on it).
    pads : per-thread search scratch for ``graph``.
    """

    city: City
    graph: RoadGraph
    counts: CountsView
    now: float
    k0: int
    workers: int
    pads: Pads
