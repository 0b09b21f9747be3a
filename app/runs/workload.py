"""Running one spec in this process: the city's bundle (network, POIs, recorded trips; read once per process
and kept), the spec's demand and tasks, the simulation and its KPIs."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from app.runs.bundles import shipped_copy
from app.runs.result import RouteRecord, RunResult
from app.runs.spec import RunJob, RunSpec, TaskTemplate
from services.city import City
from services.citydata import load_city, read_meta
from services.dispatch import warm_up
from services.model import Task, TaskId
from services.network.network import SnapError
from services.sim.demand import DemandSet
from services.sim.demand_chengdu import DemandShape, PoiDensity, chengdu_demand, poi_density, read_pois_csv
from services.sim.demand_nyc import TripRecords, manhattan_demand, read_nyc_requests
from services.sim.drift import drift_map
from services.sim.engine import RunTrace, SimConfig, poi_tasks, simulate
from services.sim.kpi import run_kpis
from services.sim.local import LocalDispatcher

__all__ = [
    "Bundle",
    "NoDemandSource",
    "check_demand_source",
    "open_bundle",
    "demand_for",
    "tasks_for",
    "placed_tasks",
    "simulate_spec",
    "run_job",
]

_TASK_STREAM = 0x7A5


class NoDemandSource(ValueError):
    """A city bundle with neither POIs nor recorded requests: no demand can be drawn on it."""

    @classmethod
    def of(cls, city: str) -> NoDemandSource:
        """The error for ``city`` (one argument, the message: it crosses to the worker's parent pickled)."""
        return cls(f"city {city!r} has neither POIs nor recorded requests to build demand from")


def check_demand_source(directory: Path) -> None:
    """``NoDemandSource`` when the bundle in ``directory`` can draw no demand of its own (its ``city.json``
    alone is read: a run that would fail anyway fails before loading a network of any size)."""
    meta = read_meta(directory)
    if "pois" not in meta.files and "requests" not in meta.files:
        raise NoDemandSource.of(meta.name)


class Bundle:
    """A city bundle and what runs draw from it (each part read on first use)."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.city: City = load_city(directory)
        self.files = read_meta(directory).files
        self._variants: dict[bool, City] = {self.city.params.active_sensing: self.city}

    def city_for(self, active: bool) -> City:
        """The city with Step 3 on or off: one object per setting for the life of the process, so that what
        is built once per city object (search graphs, landmarks, scratch, the drift's trees) is built once,
        not once per run."""
        city = self._variants.get(active)
        if city is None:
            params = dataclasses.replace(self.city.params, active_sensing=active)
            city = self._variants[active] = dataclasses.replace(self.city, params=params)
        return city

    @cached_property
    def pois(self) -> NDArray[np.float64] | None:
        """The bundle's POIs (lon, lat), if it has any."""
        return read_pois_csv(self.directory / self.files["pois"]) if "pois" in self.files else None

    @cached_property
    def density(self) -> PoiDensity | None:
        """POI density per cell, which the synthetic generator draws destinations from."""
        return None if self.pois is None else poi_density(self.city, self.pois)

    @cached_property
    def records(self) -> TripRecords:
        """The bundle's recorded trips (the bootstrap source when it has no POIs)."""
        if "requests" not in self.files:
            raise NoDemandSource.of(self.city.name)
        return read_nyc_requests(self.directory / self.files["requests"])

    @cached_property
    def candidates(self) -> NDArray[np.int64]:
        """POI nodes: the POIs snapped to the network (those within the snap limit), else every node."""
        city = self.city
        if self.pois is None:
            return np.arange(city.network.n_nodes, dtype=np.int64)
        nodes = []
        for lon, lat in self.pois:
            try:
                nodes.append(city.network.snap(float(lon), float(lat), city.params.snap_limit_m)[0])
            except SnapError:
                continue
        return np.unique(np.asarray(nodes, dtype=np.int64))


def open_bundle(directory: Path) -> Bundle:
    """The bundle in ``directory``, or its copy shipped to this process (``app.runs.bundles``); kept
    per process, the dispatch and drift kernels warmed up and the city's search structures built on first
    load."""
    return _open(shipped_copy(Path(directory)))


@lru_cache(maxsize=8)
def _open(directory: Path) -> Bundle:
    bundle = Bundle(directory)
    warm_up(bundle.city)
    drift_map(bundle.city, SimConfig().drift_radius_m).warm_up()
    return bundle


def demand_for(spec: RunSpec, bundle: Bundle) -> DemandSet:
    """The spec's demand: the calibrated generator on the bundle's POIs, else the recorded trips
    (bootstrapped for ``day > 0``)."""
    city = bundle.city
    density = bundle.density
    if density is not None:
        shape = DemandShape() if spec.rate_per_hour is None else DemandShape(rate_per_hour=spec.rate_per_hour)
        return chengdu_demand(
            city, density, seed=spec.seed, scenario=spec.scenario, day=spec.day, shape=shape
        )
    if spec.scenario != 1:
        raise ValueError("scenarios 2 and 3 exist only for the synthetic generator (Chengdu)")
    return manhattan_demand(
        city, bundle.records, seed=spec.seed, day=spec.day, rate_per_hour=spec.rate_per_hour
    )


def tasks_for(spec: RunSpec, bundle: Bundle, date: str, prefix: str = "") -> list[Task]:
    """The spec's monitoring tasks: ``n_tasks`` distinct POIs scheduled uniformly over the horizon (drawn
    for ``spec.tasks_day`` when set, so every day of a history shares one task set, else for its day)."""
    hz = bundle.city.horizon
    day = spec.day if spec.tasks_day is None else spec.tasks_day
    rng = np.random.default_rng(np.random.SeedSequence([spec.seed, day, _TASK_STREAM]))
    return poi_tasks(bundle.candidates, spec.n_tasks, hz.start_s(date), hz.length_s, rng, prefix)


def placed_tasks(templates: Sequence[TaskTemplate], bundle: Bundle, date: str) -> list[Task]:
    """Task templates placed on the horizon of local day ``date`` (pending, in template order)."""
    start = bundle.city.horizon.start_s(date)
    return [Task(TaskId(t.id), int(t.node), start + float(t.offset_s)) for t in templates]


def simulate_spec(
    spec: RunSpec,
    bundle: Bundle,
    demand: DemandSet | None = None,
    tasks: Sequence[TaskTemplate] | None = None,
    start_nodes: Sequence[int] | None = None,
) -> tuple[City, RunTrace]:
    """Simulate one spec in-process (on ``demand`` instead of the spec's own, e.g. recorded requests, on
    the platform's ``tasks`` instead of the spec's seeded draw, from ``start_nodes`` instead of seeded
    random nodes)."""
    city = bundle.city_for(spec.active)
    if demand is None:
        demand = demand_for(spec, bundle)
    config = SimConfig(
        n_instrumented=spec.n1,
        n_ordinary=spec.n0,
        n_tasks=spec.n_tasks if tasks is None else len(tasks),
        seed=spec.seed,
        wait_only=spec.wait_only,
    )
    day_tasks = (
        tasks_for(spec, bundle, demand.date) if tasks is None else placed_tasks(tasks, bundle, demand.date)
    )
    trace = simulate(city, demand, day_tasks, config, LocalDispatcher(city), start_nodes=start_nodes)
    return city, trace


def run_job(job: RunJob) -> RunResult:
    """Simulate one job in this process (top level, so an executor can send it to other processes)."""
    if job.demand is None:  # the spec's own demand, drawn from the bundle
        check_demand_source(shipped_copy(Path(job.bundle)))
    bundle = open_bundle(job.bundle)  # once per process: not part of the run's time
    started, cpu = time.perf_counter(), time.process_time()
    city, trace = simulate_spec(job.spec, bundle, job.demand, job.tasks, job.start_nodes)
    routes = None
    if job.spec.keep_routes:
        routes = tuple(
            RouteRecord(t, str(a.taxi_id), str(a.task_id), tuple(a.path)) for t, a in trace.assignments
        )
    return RunResult(
        key=job.key,
        spec=job.spec,
        demand=dict(trace.demand),
        kpis=run_kpis(city, trace),
        n_unposted=trace.n_unposted,
        elapsed_s=time.perf_counter() - started,
        routes=routes,
        cpu_s=time.process_time() - cpu,
    )
