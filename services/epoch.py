"""What every step of one decision epoch reads (docs/METHOD.md section 4)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from services.city import City
from services.model import CountsView
from services.network.graph import RoadGraph
from services.network.scratch import ScratchPool

__all__ = ["Epoch", "until_fits"]

_R = TypeVar("_R")
_S = TypeVar("_S")


@dataclass(frozen=True, slots=True)
class Epoch:
    """One epoch's shared inputs: the city and its search graph, the counts as of the epoch's start, the
    epoch's time and interval, the threads for the independent searches and their scratch pool.

    Attributes
    ----------
    city : the served city (network, grid, weights, parameters).
    graph : ``road_graph(city)``.
    counts : Lambda per interval and the (interval, cell) pairs each taxi is already counted in.
    now : the epoch's time (seconds); every path of the epoch departs then.
    k0 : the interval ``now`` falls in.
    workers : threads for the independent searches (no result depends on it).
    pool : per-thread search scratch for ``graph``.
    """

    city: City
    graph: RoadGraph
    counts: CountsView
    now: float
    k0: int
    workers: int
    pool: ScratchPool


def until_fits(attempt: Callable[[_S], tuple[_R, _S | None]], size: _S) -> tuple[_R, _S]:
    """``attempt(size)`` repeated with the size it asks for until it asks for none; its last result and the
    size that fitted. An epoch's gain tables (and the intervals the use case loads) start with the epoch's
    first intervals and grow when a path runs on past them."""
    while True:
        result, needed = attempt(size)
        if needed is None:
            return result, size
        size = needed
