"""One decision epoch: the three-step priority matching and Algorithm 2 (METHOD sections 4-6).

``decide`` is the single pure entry point: (city, counts, snapshot, tasks) -> Decision.
"""

from __future__ import annotations

from collections.abc import Sequence

from services.city import City
from services.model import CountsView, Decision, Snapshot, Task

__all__ = ["decide"]


def decide(city: City, counts: CountsView, snapshot: Snapshot, tasks: Sequence[Task]) -> Decision:
    """Solve one epoch. Pure: reads nothing but its arguments, changes nothing."""
    raise NotImplementedError
