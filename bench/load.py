"""The load a platform makes, epoch after epoch, for the epoch benchmark.

A :class:`Platform` keeps a fleet and its riders between epochs the way a ride-hailing platform does:

* taxis continue from where their committed paths took them: a matched taxi drives its pickup and trip
  path, a Step 3 taxi its monitoring route, at the network's speed, and is vacant again at the end (the
  simulator's ``services.sim.engine.Job``); a vacant taxi with no job stays where it is;
* riders wait until they are matched or their patience runs out (the service names the expired ones);
  new requests fill the waiting list up to the scenario's rider count each epoch;
* new monitoring tasks are registered every epoch and stay open until a taxi serves them (the service
  keeps their state: an open task is posted once and read by every later epoch);
* origins, destinations, POIs and the taxis' start nodes come from a :class:`Demand`: around a few
  centres on a generated city, spread over the whole network (:class:`SpreadDemand`), or drawn from a
  bundled city's recorded or synthetic requests and POIs;
* under the heaviest load (``Load.all_vacant``) every taxi is posted vacant every epoch, where its last
  path took it: the rush-hour epoch in which every driver is free at once.

Every draw is seeded, so a run is the same each time it is made, whichever path decides it (in-process or
over HTTP): a decision is a function of its inputs, and the inputs of epoch ``e`` depend only on the
decisions before it.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol
from zoneinfo import ZoneInfo

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from services.city import City
from services.model import Rider, RiderId, RiderMatch, Snapshot, Task, TaskAssignment, TaskId, Taxi, TaxiId
from services.sim.engine import Job

__all__ = ["Load", "Demand", "RecordedDemand", "CentresDemand", "SpreadDemand", "Centres", "Platform"]


@dataclass(frozen=True, slots=True)
class Load:
    """One scenario's load: fleet sizes, waiting riders posted per epoch, new tasks per epoch, the seed, and
    whether every taxi is posted vacant every epoch (where its last path took it) instead of busy until
    its path ends."""

    n_instrumented: int
    n_ordinary: int
    riders: int
    new_tasks: int
    seed: int = 20261123
    all_vacant: bool = False


class Demand(Protocol):
    """Where a platform's trips, POIs and taxis are."""

    def trips(self, rng: np.random.Generator, n: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """``n`` (origin, destination) node pairs."""
        ...

    def pois(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        """``n`` POI nodes."""
        ...

    def taxi_starts(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        """Where ``n`` taxis start the day."""
        ...


@dataclass(frozen=True, slots=True)
class RecordedDemand:
    """Trips resampled from a day of requests (a bundled city's synthetic or recorded demand), POIs from its
    POI candidates, taxis starting at request origins."""

    origins: NDArray[np.int64]
    destinations: NDArray[np.int64]
    poi_nodes: NDArray[np.int64]

    def trips(self, rng: np.random.Generator, n: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        k = rng.integers(len(self.origins), size=n)
        return self.origins[k], self.destinations[k]

    def pois(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        return self.poi_nodes[rng.integers(len(self.poi_nodes), size=n)]

    def taxi_starts(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        return self.origins[rng.integers(len(self.origins), size=n)]


class CentresDemand:
    """Demand around a city's centres: origins, POIs and taxis drawn by ``near(rng, n)`` (nodes around the
    centres), destinations at a trip length drawn from a log-normal (median ``trip_median_m``, log-sd
    ``trip_sigma``, at most ``trip_max_m``) in a uniform direction from the origin, snapped to the nearest
    node."""

    def __init__(
        self,
        city: City,
        near: NearCentres,
        trip_median_m: float = 5_000.0,
        trip_sigma: float = 0.6,
        trip_max_m: float = 30_000.0,
    ) -> None:
        self._near = near
        self._xy = np.column_stack((city.network.x_m, city.network.y_m))
        self._tree = cKDTree(self._xy)
        self._median = trip_median_m
        self._sigma = trip_sigma
        self._max = trip_max_m

    def trips(self, rng: np.random.Generator, n: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        origins = self._near(rng, n)
        length = np.minimum(self._median * np.exp(self._sigma * rng.standard_normal(n)), self._max)
        angle = rng.uniform(0.0, 2.0 * np.pi, n)
        at = self._xy[origins] + np.column_stack((np.cos(angle), np.sin(angle))) * length[:, None]
        _, dest = self._tree.query(at)
        return origins, np.asarray(dest, dtype=np.int64)

    def pois(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        return self._near(rng, n)

    def taxi_starts(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        return self._near(rng, n)


class SpreadDemand:
    """Demand spread over the whole network: origins, destinations, POIs and taxis at nodes drawn uniformly,
    so trips cross the city and every taxi is somewhere else."""

    def __init__(self, city: City) -> None:
        self._n = city.network.n_nodes

    def trips(self, rng: np.random.Generator, n: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        return self.pois(rng, n), self.pois(rng, n)

    def pois(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        return rng.integers(self._n, size=n).astype(np.int64)

    def taxi_starts(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        return self.pois(rng, n)


class NearCentres(Protocol):
    def __call__(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]: ...


class Centres:
    """Nodes drawn around centres: each draw picks a centre by weight, moves from it by a normal offset of
    standard deviation ``spread_m`` on each axis, and snaps to the nearest node."""

    def __init__(self, city: City, xy: NDArray[np.float64], weight: NDArray[np.float64], spread_m: float):
        self._tree = cKDTree(np.column_stack((city.network.x_m, city.network.y_m)))
        self._xy = np.asarray(xy, dtype=np.float64)
        self._weight = np.asarray(weight, dtype=np.float64) / float(np.sum(weight))
        self._spread = spread_m

    def __call__(self, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
        pick = rng.choice(len(self._weight), size=n, p=self._weight)
        _, idx = self._tree.query(self._xy[pick] + rng.normal(0.0, self._spread, (n, 2)))
        return np.asarray(idx, dtype=np.int64).reshape(n)

    @classmethod
    def on_bbox(cls, city: City, spread_m: float) -> Centres:
        """Four centres of a city at fixed places of its bounding box (a larger one in the middle-west)."""
        x, y = city.network.x_m, city.network.y_m
        lo, hi = np.array([x.min(), y.min()]), np.array([x.max(), y.max()])
        at = np.array([[0.35, 0.45], [0.7, 0.7], [0.65, 0.25], [0.25, 0.8]])
        return cls(city, lo + at * (hi - lo), np.array([0.4, 0.2, 0.2, 0.2]), spread_m)


class Platform:
    """A fleet and its riders over consecutive epochs (module docstring). ``next_epoch`` gives the epoch's
    snapshot and the tasks to register before it; ``apply`` takes what the service decided."""

    def __init__(self, city: City, load: Load, demand: Demand, date: tuple[int, int, int] = (2026, 11, 23)):
        self.city = city
        self.load = load
        self.demand = demand
        self._rng = np.random.default_rng(load.seed)
        tz = ZoneInfo(city.horizon.timezone)
        self._t0 = dt.datetime(*date, 8, 0, tzinfo=tz).timestamp()
        n = load.n_instrumented + load.n_ordinary
        starts = demand.taxi_starts(self._rng, n)
        self._ids = [TaxiId(f"i{k}") for k in range(load.n_instrumented)] + [
            TaxiId(f"o{k}") for k in range(load.n_ordinary)
        ]
        self._instrumented = [k < load.n_instrumented for k in range(n)]
        self._node = [int(v) for v in starts]
        self._job: list[Job | None] = [None] * n
        self._row = {t: k for k, t in enumerate(self._ids)}
        self._waiting: dict[RiderId, Rider] = {}
        self._epoch = 0
        self._riders_made = 0

    @property
    def now_s(self) -> float:
        """The time of the next epoch."""
        return self._t0 + self._epoch * self.city.horizon.epoch_s

    def next_epoch(self) -> tuple[Snapshot, list[Task]]:
        """The next epoch's snapshot (taxis moved along their jobs, riders topped up) and its new tasks."""
        now = self.now_s
        epoch_s = float(self.city.horizon.epoch_s)
        for k, job in enumerate(self._job):
            if job is None:
                continue
            self._node[k] = job.node_at(now)
            if job.done_by(now):
                self._job[k] = None
        new = max(0, self.load.riders - len(self._waiting))
        origins, dests = self.demand.trips(self._rng, new)
        asked = now - self._rng.uniform(0.0, epoch_s, new)
        for o, d, t in zip(origins.tolist(), dests.tolist(), asked.tolist(), strict=True):
            rid = RiderId(f"r{self._riders_made}")
            self._riders_made += 1
            self._waiting[rid] = Rider(rid, int(o), int(d), float(np.floor(t)))
        pois = self.demand.pois(self._rng, self.load.new_tasks)
        tasks = [Task(TaskId(f"k{self._epoch}-{i}"), int(v), now - 60.0) for i, v in enumerate(pois.tolist())]
        vacant = [self.load.all_vacant or job is None for job in self._job]
        taxis = tuple(
            Taxi(self._ids[k], self._node[k], self._instrumented[k], vacant[k]) for k in range(len(self._ids))
        )
        snap = Snapshot(f"e{self._epoch}", now, tuple(self._waiting.values()), taxis)
        self._epoch += 1
        return snap, tasks

    def apply(
        self,
        matches: Sequence[RiderMatch],
        assignments: Sequence[TaskAssignment],
        expired: Sequence[RiderId],
    ) -> None:
        """Start the jobs the service decided at the epoch just posted; drop served and expired riders."""
        now = self._t0 + (self._epoch - 1) * self.city.horizon.epoch_s
        for m in matches:
            self._job[self._row[m.taxi_id]] = Job.along(self.city, m.path, now)
            self._waiting.pop(m.rider_id, None)
        for a in assignments:
            self._job[self._row[a.taxi_id]] = Job.along(self.city, a.path, now)
        for r in expired:
            self._waiting.pop(r, None)
