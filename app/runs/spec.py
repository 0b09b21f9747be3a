"""What one simulation run is: a ``RunSpec`` (city, demand day, fleet, seed, switches) and a ``RunJob`` (the
spec, where the city's bundle lies and, for recorded demand, the demand itself)."""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from pathlib import Path

from services.sim.demand import DEMAND_VERSION, DemandSet
from services.sim.engine import SIM_VERSION

__all__ = [
    "CACHE_FORMAT",
    "RunSpec",
    "TaskTemplate",
    "RunJob",
    "demand_digest",
    "nodes_digest",
    "tasks_digest",
]

CACHE_FORMAT = "2"
"""Version of the cached result document (``RunResult.to_json``); part of every job key."""


@dataclass(frozen=True, slots=True)
class RunSpec:
    """One run. ``wait_only`` is the price-of-sensing baseline (every taxi matched as ordinary).

    Everything random in a run derives from ``seed`` and ``day`` (demand, taxi start nodes, task POIs and
    times, drift), so a spec names one reproducible run. ``tasks_day`` fixes the task draw across days
    (docs/METHOD.md section 8: uncertainty from demand, one task set for every simulated day).
    """

    city: str = "chengdu"
    scenario: int = 1
    n1: int = 60
    n0: int = 60
    seed: int = 0
    day: int = 0
    active: bool = True
    wait_only: bool = False
    n_tasks: int = 85
    rate_per_hour: float | None = None  # None: the city's default (Chengdu 144/h; Manhattan the real day)
    keep_routes: bool = False  # keep the Step 3 paths in the result (for the route figure)
    tasks_day: int | None = None  # draw the POI tasks as for this day (None: the spec's own day)

    @property
    def key(self) -> str:
        """File-name-safe identity of the run."""
        rate = "" if self.rate_per_hour is None else f"-q{self.rate_per_hour:g}"
        mode = "w" if self.wait_only else ("a" if self.active else "p")
        tasks = "" if self.tasks_day is None else f"-T{self.tasks_day}"
        return (
            f"{self.city}-s{self.scenario}-x{self.n1}-o{self.n0}-seed{self.seed}-d{self.day}-{mode}"
            f"-t{self.n_tasks}{rate}{tasks}"
        )

    def baseline(self) -> RunSpec:
        """The same run matched on wait alone."""
        return dataclasses.replace(self, active=False, wait_only=True, keep_routes=False)


@dataclass(frozen=True, slots=True)
class TaskTemplate:
    """A registered monitoring task as a day template: its id, POI node and the seconds after the start of
    the operating horizon it is scheduled at (placed on each simulated day's date)."""

    id: str
    node: int
    offset_s: float


@dataclass(frozen=True, slots=True)
class RunJob:
    """A spec ready to run anywhere: the city's bundle directory and, when the day is recorded rather than
    generated, its demand (``None``: the spec's own synthetic or bootstrapped day)."""

    spec: RunSpec
    bundle: Path
    demand: DemandSet | None = None
    tasks: tuple[TaskTemplate, ...] | None = None  # the platform's tasks (None: the spec's seeded draw)
    start_nodes: tuple[int, ...] | None = None  # the taxis' start nodes, instrumented first (None: seeded)

    @property
    def key(self) -> str:
        """Cache key (file-name safe): the spec, the recorded demand's digest, the simulator's and the
        demand generator's versions and the result format, so a changed input never reads a stale run.
        (A rebuilt city bundle is not part of the key: clear the cache when a bundle changes.)"""
        source = "syn" if self.demand is None else f"rec{demand_digest(self.demand)}"
        tasks = "" if self.tasks is None else f"-reg{tasks_digest(self.tasks)}"
        start = "" if self.start_nodes is None else f"-st{nodes_digest(self.start_nodes)}"
        return f"{self.spec.key}-{source}{tasks}{start}-sim{SIM_VERSION}-dem{DEMAND_VERSION}-c{CACHE_FORMAT}"

    @property
    def cost(self) -> float:
        """Rough relative cost, to start the long runs first (the workers then finish together)."""
        s = self.spec
        return s.n1 * (4.0 if s.active and not s.wait_only else 1.0) + s.n0 * 0.2


def demand_digest(demand: DemandSet) -> str:
    """16 hex digits of sha256 over the set's date and requests."""
    h = hashlib.sha256(demand.date.encode())
    for r in demand.requests:
        h.update(f"\n{r.id}\t{int(r.time_s)}\t{r.origin}\t{r.destination}".encode())
    return h.hexdigest()[:16]


def nodes_digest(nodes: tuple[int, ...]) -> str:
    """16 hex digits of sha256 over start nodes."""
    return hashlib.sha256(",".join(map(str, nodes)).encode()).hexdigest()[:16]


def tasks_digest(tasks: tuple[TaskTemplate, ...]) -> str:
    """16 hex digits of sha256 over the task templates."""
    h = hashlib.sha256(b"tasks")
    for t in tasks:
        h.update(f"\n{t.id}\t{t.node}\t{t.offset_s!r}".encode())
    return h.hexdigest()[:16]
