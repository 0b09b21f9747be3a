"""One simulation run, fully described by a ``RunSpec``: which city, demand, fleet, seed and switches.

Everything random in a run derives from the spec's seed and day (demand, taxi start nodes, task POIs and
times, drift), so a spec names one reproducible run. Bundle files (POIs, recorded requests) are read once
per process and cached.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.cities import BUNDLED_DIR, CityRegistry
from services.city import City
from services.citydata import read_meta
from services.dispatch import warm_up
from services.network import SnapError
from services.sim.demand import DemandSet
from services.sim.demand_chengdu import PoiDensity, chengdu_demand, poi_density, read_pois_csv
from services.sim.demand_nyc import TripRecords, manhattan_demand, read_nyc_requests
from services.sim.engine import RunTrace, SimConfig, poi_tasks, simulate
from services.sim.kpi import run_kpis
from services.sim.local import LocalDispatcher

__all__ = ["RunSpec", "load", "demand_for", "tasks_for", "run_spec", "run_result"]

_TASK_STREAM = 0x7A5


@dataclass(frozen=True, slots=True)
class RunSpec:
    """One run. ``wait_only`` is the price-of-sensing baseline (every taxi matched as ordinary)."""

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

    @property
    def key(self) -> str:
        """File-name-safe identity of the run."""
        rate = "" if self.rate_per_hour is None else f"-q{self.rate_per_hour:g}"
        mode = "w" if self.wait_only else ("a" if self.active else "p")
        return (
            f"{self.city}-s{self.scenario}-x{self.n1}-o{self.n0}-seed{self.seed}-d{self.day}-{mode}"
            f"-t{self.n_tasks}{rate}"
        )

    def baseline(self) -> RunSpec:
        """The same run matched on wait alone."""
        return dataclasses.replace(self, active=False, wait_only=True, keep_routes=False)


@lru_cache(maxsize=8)
def load(name: str, bundled_dir: Path = BUNDLED_DIR) -> tuple[City, Path]:
    """The city and its bundle directory (cached per process; kernels warmed up)."""
    registry = CityRegistry(bundled_dir)
    city = registry.get(name)
    warm_up(city)
    return city, registry.bundle_dir(name)


@lru_cache(maxsize=8)
def _pois(name: str) -> NDArray[np.float64] | None:
    city, bundle = load(name)
    files = read_meta(bundle).files
    return read_pois_csv(bundle / files["pois"]) if "pois" in files else None


@lru_cache(maxsize=8)
def _density(name: str) -> PoiDensity | None:
    pois = _pois(name)
    return None if pois is None else poi_density(load(name)[0], pois)


@lru_cache(maxsize=4)
def _records(name: str) -> TripRecords:
    city, bundle = load(name)
    files = read_meta(bundle).files
    if "requests" not in files:
        raise ValueError(f"city {name!r} has neither POIs nor recorded requests to build demand from")
    return read_nyc_requests(bundle / files["requests"])


def demand_for(spec: RunSpec) -> DemandSet:
    """The run's demand: Chengdu's calibrated generator, or the recorded requests (bootstrapped for day > 0)."""
    city, _ = load(spec.city)
    density = _density(spec.city)
    if density is not None:
        kwargs: dict[str, Any] = {} if spec.rate_per_hour is None else {"rate_per_hour": spec.rate_per_hour}
        return chengdu_demand(city, density, seed=spec.seed, scenario=spec.scenario, day=spec.day, **kwargs)
    if spec.scenario != 1:
        raise ValueError("scenarios 2 and 3 exist only for the synthetic generator (Chengdu)")
    return manhattan_demand(
        city, _records(spec.city), seed=spec.seed, day=spec.day, rate_per_hour=spec.rate_per_hour
    )


@lru_cache(maxsize=8)
def _candidates(name: str) -> NDArray[np.int64]:
    """POI nodes: the bundle's POIs snapped to the network (those within the snap limit), else every node."""
    city, _ = load(name)
    pois = _pois(name)
    if pois is None:
        return np.arange(city.network.n_nodes, dtype=np.int64)
    nodes = []
    for lon, lat in pois:
        try:
            nodes.append(city.network.snap(float(lon), float(lat), city.params.snap_limit_m)[0])
        except SnapError:
            continue
    return np.unique(np.asarray(nodes, dtype=np.int64))


def tasks_for(spec: RunSpec, date: str, prefix: str = "") -> list[Any]:
    """The run's monitoring tasks: ``n_tasks`` distinct POIs scheduled uniformly over the horizon."""
    city, _ = load(spec.city)
    rng = np.random.default_rng(np.random.SeedSequence([spec.seed, spec.day, _TASK_STREAM]))
    start = city.horizon.start_s(date)
    return poi_tasks(_candidates(spec.city), spec.n_tasks, start, city.horizon.length_s, rng, prefix)


def run_spec(spec: RunSpec, demand: DemandSet | None = None) -> tuple[City, RunTrace]:
    """Simulate one spec in-process (on ``demand`` instead of the spec's own, e.g. recorded requests)."""
    city, _ = load(spec.city)
    if city.params.active_sensing != spec.active:
        city = dataclasses.replace(city, params=dataclasses.replace(city.params, active_sensing=spec.active))
    if demand is None:
        demand = demand_for(spec)
    config = SimConfig(
        n_instrumented=spec.n1,
        n_ordinary=spec.n0,
        n_tasks=spec.n_tasks,
        seed=spec.seed,
        wait_only=spec.wait_only,
    )
    trace = simulate(city, demand, tasks_for(spec, demand.date), config, LocalDispatcher(city))
    return city, trace


def _clean(value: Any) -> Any:
    """JSON-safe: NaN becomes None."""
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def run_result(spec: RunSpec) -> dict[str, Any]:
    """Simulate one spec and return its JSON-ready result (spec, demand manifest, KPIs, hours, tasks)."""
    started = time.perf_counter()
    city, trace = run_spec(spec)
    k = run_kpis(city, trace)
    out: dict[str, Any] = {
        "spec": dataclasses.asdict(spec),
        "key": spec.key,
        "demand": trace.demand,
        "kpis": {name: _clean(v) for name, v in k.scalars().items()},
        "hours": [{n: _clean(v) for n, v in dataclasses.asdict(h).items()} for h in k.hours],
        "tasks": [{n: _clean(v) for n, v in dataclasses.asdict(t).items()} for t in k.tasks],
        "n_unposted": trace.n_unposted,
        "elapsed_s": time.perf_counter() - started,
    }
    if spec.keep_routes:
        out["routes"] = [
            {"time_s": t, "taxi_id": a.taxi_id, "task_id": a.task_id, "path": list(a.path)}
            for t, a in trace.assignments
        ]
    return out
