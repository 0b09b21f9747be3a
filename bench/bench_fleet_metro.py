"""Fleet sizing at metropolitan scale: a simulated day of a 5,000-taxi platform on the generated metropolitan
network in one engine process (time, where it goes, peak memory), the runs of one re-solve on a Dask cluster
of this machine, and how many engine processes a re-solve needs to finish within its lead time.

    python -m bench.bench_fleet_metro                # the measurement below (about 15 minutes on 2 cores)
    python -m bench.bench_fleet_metro --smoke --out DIR   # a small city and fleet, 2 days, 2 runs (the test)
    python -m bench.bench_fleet_metro --report-only docs/perf_fleet_metro.json

The city is ``bench.metro.metro_city()`` (metro250k) written as a bundle (``network.npz``, ``city.json``) into
a temporary directory and read back as every engine process reads a bundle. The platform (``FULL``): 1,500
instrumented and 3,500 ordinary taxis; about 6,000 requests an hour (a Poisson count per day, times uniform
over the horizon), origins around the city's five centres and trip lengths log-normal around 5 km
(``bench.load.CentresDemand`` on ``bench.metro.centre_layout``, 2.5 km spread, as the epoch benchmark draws
them), a seeded set per day; 400 registered POI tasks at distinct nodes around the centres, scheduled
uniformly over the horizon, the same every day; the taxis start where the platform's stood at 08:00 (drawn
around the centres, seeded per day), as the fleet worker starts a simulated fleet from a recorded day
(``app.usecases.fleet_history.start_nodes``); the city's horizon (08:00-12:00, 72 epochs of 200 s).

* **A day in one engine process.** A freshly spawned process (as a Dask worker or a local pool's process
  starts) opens the bundle (read, search structures, kernels: ``app.runs.open_bundle``, timed apart), then
  simulates ``days`` days one after another (``services.sim.engine.simulate`` with the in-process core, then
  the run's KPIs, as ``app.runs.run_job`` does), each timed, split into the core's phases, the drift and the
  rest, and the process's peak resident memory (VmHWM) read after each.
* **The map the bounded drift replaces**, measured in the same run: a few whole-network reverse trees timed
  with scipy, times the cells, and the bytes of its three dense (cells x nodes) arrays.
* **A re-solve.** Its runs are the candidate sizes (a quarter to twice the instrumented fleet: 375, 750,
  1,125, 1,500, 2,250, 3,000: ``app.usecases.fleet_history.spread_sizes``) x M = 10 days with the ordinary
  fleet (3,500), as the fleet worker derives them from the fleet a platform posts (docs/FLEET.md). Measured: every size on ``cluster_days`` day(s), on a Dask
  cluster of ``workers`` single-threaded engine processes (``app.runs.localcluster``) through the runner and
  the Dask executor, from an empty run cache, each process having opened the bundle first (timed). Scaled
  honestly: every one of the M days of a size is taken to cost the mean measured run of that size; the
  engine processes a re-solve needs are the fewest whose longest-first schedule of those runs (each process
  opening the bundle first) ends within the lead time, 45 minutes.

The machine is shared (2 cores, other work running): the load average is recorded around every measurement.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import multiprocessing
import os
import resource
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse.csgraph as cg
from numpy.typing import NDArray

from app.runs import RunCache, RunJob, Runner, RunSpec, TaskTemplate, open_bundle
from app.runs.dask_executor import DaskExecutor
from app.runs.localcluster import LocalCluster
from app.runs.workload import Bundle, placed_tasks
from app.usecases.fleet_history import RecordedFleet, SizingConfig, spread_sizes, start_nodes
from bench import metro
from bench.load import Centres, CentresDemand
from bench.report import ROOT, stamp, write_section
from services.city import City
from services.citydata import CityMeta, load_city, save_bundle
from services.model import IntervalKey, Snapshot, Task
from services.sim.demand import DemandSet, Request
from services.sim.drift import Drift, drift_map, hubs_of_cells
from services.sim.engine import SimConfig, simulate
from services.sim.kpi import run_kpis
from services.sim.local import LocalDispatcher, Outcome

CITY = "metro250k"
LEAD_S = 45 * 60.0
DAY_TARGET_S = 120.0
RSS_TARGET_MB = 2048.0
PHASES = ("view", "pickups", "trips", "step1", "step2", "step3", "algorithm2", "tasks", "commit")


@dataclass(frozen=True)
class Setup:
    """A configuration of the benchmark (its inputs, as data)."""

    scale: float  # of bench.metro's square (1.0: metro250k)
    spread_m: float  # of the draws around the centres
    n1: int  # instrumented taxis the platform posts
    n0: int  # ordinary taxis
    rate_per_hour: float
    n_tasks: int
    days: int  # simulated one after another in one engine process
    sizes: tuple[int, ...]  # a re-solve's candidate N1
    m_days: int  # M, the days of a re-solve
    cluster_days: int  # days per size run on the cluster
    workers: int  # Dask engine processes
    dense_trees: int  # whole trees timed for the dense map's estimate
    seed: int = 20261123


FULL = Setup(1.0, 2_500.0, 1500, 3500, 6000.0, 400, 3, spread_sizes(1500), SizingConfig().days, 1, 2, 8)
SMOKE = Setup(0.1, 300.0, 4, 8, 60.0, 5, 2, spread_sizes(4), SizingConfig().days, 1, 1, 2)


@dataclass(frozen=True)
class PlatformDay:
    """A day of the platform's history: its requests and its fleet (where its taxis stood at 08:00)."""

    demand: DemandSet
    fleet: RecordedFleet

    def starts(self, n1: int, setup: Setup) -> tuple[int, ...]:
        """Where a simulated fleet of ``n1`` instrumented taxis (and the ordinary fleet) starts that day, as
        the fleet worker starts it (``app.usecases.fleet_history.start_nodes``)."""
        date = dt.date.fromisoformat(self.demand.date)
        nodes = start_nodes(self.fleet, date, n1, setup.n0, setup.seed)
        assert nodes is not None  # the fleet has positions
        return tuple(int(v) for v in nodes)


# ---------------------------------------------------------------------------------------------- the inputs


def write_bundle(setup: Setup, directory: Path) -> Path:
    """The generated city as a bundle under ``directory``; its path."""
    city = metro.metro_city(scale=setup.scale)
    meta = CityMeta(name=CITY, timezone="Asia/Shanghai", source="generated (bench.metro)")
    return save_bundle(directory / CITY, city.network, meta)


def centres(city: City, setup: Setup) -> Centres:
    """Node draws around the city's centres."""
    pos, weight = metro.centre_layout(city)
    return Centres(city, pos, weight, setup.spread_m)


def platform_day(city: City, near: Centres, setup: Setup, day: int, date: str) -> PlatformDay:
    """One day of requests and the fleet's positions at 08:00 (module docstring), seeded by (seed, day)."""
    rng = np.random.default_rng([setup.seed, 1, day])
    hz = city.horizon
    start = hz.start_s(date)
    n = int(rng.poisson(setup.rate_per_hour * hz.length_s / 3600.0))
    times = np.floor(start + rng.random(n) * hz.length_s)
    trip_median = 5_000.0 * setup.scale**0.5  # shorter trips on a shrunken city
    origins, dests = CentresDemand(city, near, trip_median_m=trip_median).trips(rng, n)
    reqs = [
        Request(f"d{day}-{i:05d}", float(t), int(o), int(d))
        for i, (t, o, d) in enumerate(zip(times.tolist(), origins.tolist(), dests.tolist(), strict=True))
        if o != d
    ]
    reqs.sort(key=lambda r: (r.time_s, r.id))
    demand = DemandSet(CITY, date, tuple(reqs), "bench-centres", seed=setup.seed, params={"day": day})
    at = np.random.default_rng([setup.seed, 3, day])
    return PlatformDay(demand, RecordedFleet(setup.n1, setup.n0, near(at, setup.n1), near(at, setup.n0)))


def platform_tasks(city: City, near: Centres, setup: Setup) -> tuple[TaskTemplate, ...]:
    """The registered tasks: distinct nodes around the centres, scheduled uniformly over the horizon."""
    rng = np.random.default_rng([setup.seed, 2])
    nodes = np.unique(near(rng, 20 * setup.n_tasks))
    chosen = rng.choice(nodes, size=setup.n_tasks, replace=False)
    offsets = np.sort(np.floor(rng.random(setup.n_tasks) * city.horizon.length_s))
    return tuple(
        TaskTemplate(f"poi{i:03d}", int(v), float(o))
        for i, (v, o) in enumerate(zip(chosen.tolist(), offsets.tolist(), strict=True))
    )


def dates(n: int) -> list[str]:
    """``n`` consecutive local dates."""
    return [f"2026-11-{d:02d}" for d in range(2, 2 + n)]


# ----------------------------------------------------------------------------- a day in one engine process


def peak_mb() -> float:
    """This process's peak resident memory (VmHWM), MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class _Clock:
    """Seconds spent per phase of the core (laps of ``LocalDispatcher``'s stopwatch) and in the drift."""

    def __init__(self) -> None:
        self.spent: dict[str, float] = {}
        self._last = 0.0

    def start(self) -> None:
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.add(name, now - self._last)
        self._last = now

    def add(self, name: str, seconds: float) -> None:
        self.spent[name] = self.spent.get(name, 0.0) + seconds


class _TimedDispatcher:
    """``LocalDispatcher`` with its phases timed."""

    def __init__(self, city: City, clock: _Clock) -> None:
        self.inner = LocalDispatcher(city, phase=clock.lap)
        self.clock = clock

    def add_tasks(self, tasks: Sequence[Task]) -> None:
        self.inner.add_tasks(tasks)

    def epoch(self, snapshot: Snapshot) -> Outcome:
        self.clock.start()
        return self.inner.epoch(snapshot)

    def tasks(self) -> list[Task]:
        return self.inner.tasks()

    def interval_counts(self, k: IntervalKey) -> NDArray[np.int64]:
        return self.inner.interval_counts(k)


class _TimedDrift:
    """The process's drift map with its draws and walks timed."""

    def __init__(self, inner: Drift, clock: _Clock) -> None:
        self.inner = inner
        self.clock = clock

    @property
    def node_cell(self) -> NDArray[np.int64]:
        return self.inner.node_cell

    @property
    def hubs(self) -> NDArray[np.int64]:
        return self.inner.hubs

    def choose_target(self, node: int, density: NDArray[np.float64], rng: np.random.Generator) -> int:
        t = time.perf_counter()
        row = self.inner.choose_target(node, density, rng)
        self.clock.add("drift", time.perf_counter() - t)
        return row

    def walk(self, hub_row: int, node: int, budget_s: float) -> tuple[int, float]:
        t = time.perf_counter()
        out = self.inner.walk(hub_row, node, budget_s)
        self.clock.add("drift", time.perf_counter() - t)
        return out


def simulate_day(
    bundle: Bundle, day: PlatformDay, tasks: tuple[TaskTemplate, ...], setup: Setup
) -> dict[str, Any]:
    """One day as ``run_job`` simulates it (the core in-process, then the KPIs), timed by part."""
    demand = day.demand
    city = bundle.city_for(True)
    config = SimConfig(setup.n1, setup.n0, len(tasks), seed=setup.seed)
    dm = drift_map(city, config.drift_radius_m)
    grown = dm.stats().grown
    clock = _Clock()
    started, cpu = time.perf_counter(), time.process_time()
    trace = simulate(
        city, demand, placed_tasks(tasks, bundle, demand.date), config,
        _TimedDispatcher(city, clock), start_nodes=day.starts(setup.n1, setup), drift=_TimedDrift(dm, clock),
    )  # fmt: skip
    simulated = time.perf_counter()
    kpis = run_kpis(city, trace)
    wall = time.perf_counter() - started
    clock.add("kpis", wall - (simulated - started))
    clock.add("simulator", wall - sum(clock.spent.values()))
    return {
        "wall_s": wall, "cpu_s": time.process_time() - cpu, "peak_mb": peak_mb(), "spent_s": clock.spent,
        "requests": len(demand.requests),
        "matching_rate": kpis.matching_rate, "step3_routes": len(trace.assignments),
        "trees_grown": dm.stats().grown - grown,
    }  # fmt: skip


def engine_days(
    bundle_dir: Path, days: list[PlatformDay], tasks: tuple[TaskTemplate, ...], setup: Setup
) -> dict[str, Any]:
    """In a fresh process: open the bundle, then simulate the days one after another."""
    t, cpu = time.perf_counter(), time.process_time()
    bundle = open_bundle(bundle_dir)
    opened = {
        "open_s": time.perf_counter() - t,
        "open_cpu_s": time.process_time() - cpu,
        "open_peak_mb": peak_mb(),
    }
    out = []
    for day in days:
        out.append(simulate_day(bundle, day, tasks, setup))
        d = out[-1]
        print(
            f"  day {day.demand.date}: {d['wall_s']:.1f} s ({d['cpu_s']:.1f} s CPU), peak {d['peak_mb']:.0f} MB",
            flush=True,
        )
    stats = drift_map(bundle.city_for(True), SimConfig().drift_radius_m).stats()
    return {**opened, "days": out, "drift": dataclasses.asdict(stats)}


def in_fresh_process(
    bundle_dir: Path, days: list[PlatformDay], tasks: tuple[TaskTemplate, ...], setup: Setup
) -> dict[str, Any]:
    """``engine_days`` in a newly spawned process (nothing of this one's memory or caches)."""
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(engine_days, bundle_dir, days, tasks, setup).result()


def dense_map(city: City, n_trees: int) -> dict[str, Any]:
    """What the dense drift map (a whole-network reverse tree per cell, cells x nodes) would cost: the first
    ``n_trees`` hubs' trees timed with scipy (each as its own call), and its arrays' bytes."""
    _, hubs, _, _, _ = hubs_of_cells(city)
    reverse = city.network.csr(city.network.edge_time_s).T.tocsr()
    took = []
    for h in hubs[:n_trees]:
        t = time.perf_counter()
        cg.dijkstra(reverse, directed=True, indices=[int(h)], return_predecessors=True)
        took.append(time.perf_counter() - t)
    per_tree = float(np.median(took))
    entry_bytes = 8 + 4 + 4  # time (float64), scipy's predecessors and the next node (int32)
    return {
        "cells": int(hubs.size), "nodes": city.network.n_nodes, "tree_ms": 1000.0 * per_tree,
        "trees_timed": len(took), "build_s": per_tree * hubs.size,
        "gb": hubs.size * city.network.n_nodes * entry_bytes / 1e9,
    }  # fmt: skip


# ------------------------------------------------------------------------------------------------ a re-solve


def resolve_jobs(
    bundle_dir: Path, days: list[PlatformDay], tasks: tuple[TaskTemplate, ...], setup: Setup
) -> list[RunJob]:
    """The re-solve's runs over ``days``: one whole-day job per (size, day), as the fleet worker makes them
    (the day's requests, the registered tasks, the fleet starting where the day's taxis stood)."""
    return [
        RunJob(
            RunSpec(CITY, n1=x, n0=setup.n0, seed=setup.seed, day=i, n_tasks=len(tasks)),
            bundle_dir,
            d.demand,
            tasks,
            start_nodes=d.starts(x, setup),
        )  # fmt: skip
        for x in setup.sizes
        for i, d in enumerate(days)
    ]


def _open_timed(bundle_dir: str) -> dict[str, float]:
    """On an engine process: open the bundle; the wall and processor seconds it took."""
    t, cpu = time.perf_counter(), time.process_time()
    open_bundle(Path(bundle_dir))
    return {"elapsed_s": time.perf_counter() - t, "cpu_s": time.process_time() - cpu}


def on_cluster(bundle_dir: Path, jobs: list[RunJob], setup: Setup, tmp: Path) -> dict[str, Any]:
    """The jobs on a local Dask cluster from an empty cache: every engine process opens the bundle first."""
    with LocalCluster(setup.workers, tmp / "cluster", start_timeout_s=120.0) as cluster:
        executor = DaskExecutor(cluster.address, timeout_s=60.0)
        try:
            executor.ship(bundle_dir)
            opened = cluster.run(_open_timed, str(bundle_dir))
            loads = [os.getloadavg()[0]]
            started = time.perf_counter()
            batch = Runner(RunCache(tmp / "runs"), executor).run(jobs)
            wall = time.perf_counter() - started
            loads.append(os.getloadavg()[0])
            peaks = cluster.run(peak_mb)
        finally:
            executor.close()
    if batch.failures:
        raise RuntimeError(f"runs failed on the cluster: {batch.failures}")
    runs: list[dict[str, Any]] = [
        {
            "n1": r.spec.n1,
            "day": r.spec.day,
            "elapsed_s": r.elapsed_s,
            "cpu_s": r.cpu_s,
            "requests": r.n_requests,
            "matching_rate": r.kpis.matching_rate,
        }
        for r in sorted(batch.results.values(), key=lambda r: (r.spec.n1, r.spec.day))
    ]
    model = schedule_s([r["elapsed_s"] for r in runs], setup.workers, 0.0)
    return {
        "workers": setup.workers, "wall_s": wall, "runs": runs, "open": list(opened.values()),
        "peak_mb": sorted(peaks.values()), "load": loads, "schedule_s": model, "overhead": wall / model,
    }  # fmt: skip


def schedule_s(durations: Sequence[float], processes: int, open_s: float) -> float:
    """When the last of ``durations`` ends on ``processes`` engine processes, each opening the bundle first
    (``open_s``), the longest runs started first, each on the process free earliest."""
    ends = [open_s] * processes
    for d in sorted(durations, reverse=True):
        i = int(np.argmin(ends))
        ends[i] += d
    return max(ends)


def processes_needed(durations: Sequence[float], open_s: float, lead_s: float = LEAD_S) -> int | None:
    """The fewest engine processes that finish ``durations`` within ``lead_s`` (``schedule_s``); ``None``
    when even one process per run cannot."""
    for p in range(1, len(durations) + 1):
        if schedule_s(durations, p, open_s) <= lead_s:
            return p
    return None


def project(cluster: dict[str, Any], setup: Setup, basis: str) -> dict[str, Any]:
    """The whole re-solve (sizes x M days) from the measured runs, each run taking its ``basis`` time
    (``cpu_s``: its processor time, what a core of its own would take; ``elapsed_s``: its wall time as measured
    here): each size's mean for each of its M days; their sum, the re-solve's wall on a cluster like the one
    measured (the schedule times the measured cluster's wall over its own schedule) and the engine processes
    it needs for the lead time."""
    by_size = {x: float(np.mean([r[basis] for r in cluster["runs"] if r["n1"] == x])) for x in setup.sizes}
    durations = [by_size[x] for x in setup.sizes for _ in range(setup.m_days)]
    open_s = max(o[basis] for o in cluster["open"])
    need = processes_needed(durations, open_s)
    return {
        "run_s_by_size": {str(x): v for x, v in by_size.items()}, "runs": len(durations),
        "total_s": float(sum(durations)), "open_s": open_s,
        "wall_on_cluster_s": schedule_s(durations, setup.workers, open_s) * cluster["overhead"],
        "processes": need, "makespan_s": None if need is None else schedule_s(durations, need, open_s),
        "lower_bound": math.ceil(sum(durations) / LEAD_S),
    }  # fmt: skip


# ------------------------------------------------------------------------------------------ the measurement


def summary(values: Sequence[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64)
    return {"n": int(a.size), "median": float(np.median(a)), "min": float(a.min()), "max": float(a.max())}


def measure(setup: Setup, tmp: Path) -> dict[str, Any]:
    """Every measurement of the module docstring, with its inputs and the load around each."""
    t = time.perf_counter()
    bundle_dir = write_bundle(setup, tmp)
    city = load_city(bundle_dir)
    near = centres(city, setup)
    tasks = platform_tasks(city, near, setup)
    days = [
        platform_day(city, near, setup, d, date)
        for d, date in enumerate(dates(max(setup.days, setup.cluster_days)))
    ]
    prepared_s = time.perf_counter() - t
    print(
        f"{city.network.n_nodes:,} nodes, {len(days[0].demand.requests):,} requests a day; prepared in {prepared_s:.0f} s",
        flush=True,
    )
    loads = {"engine": [os.getloadavg()[0]]}
    engine = in_fresh_process(bundle_dir, days[: setup.days], tasks, setup)
    loads["engine"].append(os.getloadavg()[0])
    dense = dense_map(city, setup.dense_trees)
    print(
        f"re-solve subset: sizes {setup.sizes} x {setup.cluster_days} day(s) on {setup.workers} Dask worker(s)",
        flush=True,
    )
    jobs = resolve_jobs(bundle_dir, days[: setup.cluster_days], tasks, setup)
    cluster = on_cluster(bundle_dir, jobs, setup, tmp)
    return {
        "setup": dataclasses.asdict(setup), "nodes": city.network.n_nodes, "edges": city.network.n_edges,
        "requests_per_day": [len(d.demand.requests) for d in days], "engine": engine, "dense": dense,
        "cluster": cluster, "load": loads, "cpus": os.cpu_count(),
        "resolve": {"cpu": project(cluster, setup, "cpu_s"), "wall": project(cluster, setup, "elapsed_s")},
    }  # fmt: skip


# ---------------------------------------------------------------------------------------------- the report


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def _day_lines(res: dict[str, Any]) -> list[str]:
    s, eng = res["setup"], res["engine"]
    walls = summary([d["wall_s"] for d in eng["days"]])
    cpus = summary([d["cpu_s"] for d in eng["days"]])
    peak = max(d["peak_mb"] for d in eng["days"])
    total = {
        k: float(np.median([d["spent_s"].get(k, 0.0) for d in eng["days"]]))
        for k in (*PHASES, "drift", "kpis", "simulator")
    }
    core = sum(total[p] for p in PHASES)
    grown = [d["trees_grown"] for d in eng["days"]]
    drift = eng["drift"]
    ld = res["load"]["engine"]
    return [
        f"**A simulated day in one engine process** ({s['n1']:,} instrumented + {s['n0']:,} ordinary taxis, "
        f"{summary(res['requests_per_day'][: s['days']])['median']:,.0f} requests a day, {s['n_tasks']} tasks, 72 epochs; "
        f"{walls['n']} days one after another in a freshly spawned process; load average {ld[0]:.1f} before, {ld[1]:.1f} after, "
        f"on {res['cpus']} cores):",
        "",
        f"- opening the bundle (read, search structures, kernels warmed up): {eng['open_s']:.1f} s "
        f"({eng['open_cpu_s']:.1f} s of processor time), peak {eng['open_peak_mb']:.0f} MB;",
        f"- a day: **{walls['median']:.1f} s** wall, median ({walls['min']:.1f}-{walls['max']:.1f}); **{cpus['median']:.1f} s** of "
        f"processor time ({cpus['min']:.1f}-{cpus['max']:.1f}), what a core of its own takes. Target {DAY_TARGET_S:.0f} s: "
        f"{_verdict(cpus['max'] <= DAY_TARGET_S)} on processor time, {_verdict(walls['max'] <= DAY_TARGET_S)} on the wall "
        "time at this load;",
        f"- the process's peak resident memory after its last day: **{peak:.0f} MB** (target {RSS_TARGET_MB:.0f} MB: "
        f"{_verdict(peak <= RSS_TARGET_MB)});",
        f"- the drift grew {grown[0]:,} hub trees on the first day and {', '.join(f'{g:,}' for g in grown[1:]) or 'none'} on "
        f"the next (trees are kept per process), {drift['settled'] / max(drift['grown'], 1):,.0f} nodes settled per tree on "
        f"average; it holds {drift['held']:,} trees, {drift['held_bytes'] / 2**20:.0f} MB.",
        "",
        "Where a day's wall time goes (median seconds over the days; `view` and `commit`: the in-process "
        "dispatcher reading and committing the counts; the simulator's own: moving taxis, posting riders, building "
        "snapshots, applying decisions):",
        "",
        "| the core | " + " | ".join(PHASES) + " | drift | KPIs | the simulator's own |",
        "|---" * (len(PHASES) + 4) + "|",
        f"| {core:.1f} | " + " | ".join(f"{total[p]:.1f}" for p in PHASES)
        + f" | {total['drift']:.1f} | {total['kpis']:.1f} | {total['simulator']:.1f} |",
    ]  # fmt: skip


def _dense_lines(res: dict[str, Any]) -> list[str]:
    d, eng = res["dense"], res["engine"]
    return [
        f"**The dense drift map this replaces** (one whole-network reverse tree per cell): {d['cells']:,} cells x "
        f"{d['nodes']:,} nodes; a whole tree takes {d['tree_ms']:.0f} ms with scipy here (median of {d['trees_timed']}), "
        f"so {d['build_s']:.0f} s before the first epoch, and its three arrays (time, predecessor, next node) take "
        f"{d['gb']:.1f} GB. The bounded map's trees: {eng['drift']['held_bytes'] / 2**20:.0f} MB after {len(eng['days'])} days.",
    ]  # fmt: skip


def _needs(r: dict[str, Any]) -> str:
    if r["processes"] is None:
        return "no number of engine processes (one run alone is longer)"
    return f"{r['processes']} engine processes (the longest-first schedule ends after {r['makespan_s'] / 60:.1f} min)"


def _resolve_lines(res: dict[str, Any]) -> list[str]:
    s, c, cpu, wall = res["setup"], res["cluster"], res["resolve"]["cpu"], res["resolve"]["wall"]
    sizes = ", ".join(f"{int(x):,}" for x in s["sizes"])
    by_size = ", ".join(
        f"{int(x):,}: {cpu['run_s_by_size'][x]:.0f} s ({wall['run_s_by_size'][x]:.0f} s wall)"
        for x in cpu["run_s_by_size"]
    )
    opened = ", ".join(f"{o['elapsed_s']:.0f}" for o in c["open"])
    return [
        f"**A re-solve.** Sizes {sizes} x M = {s['m_days']} days = {cpu['runs']} whole-day runs ({s['n0']:,} ordinary taxis). "
        f"Measured: every size on {s['cluster_days']} day(s), {len(c['runs'])} runs on a Dask cluster of {c['workers']} "
        f"single-threaded engine processes on this machine (load average {c['load'][0]:.1f} before, {c['load'][-1]:.1f} after), "
        f"from an empty run cache: {c['wall_s']:.0f} s wall, {c['overhead']:.2f}x the longest-first schedule of the runs' own "
        f"wall times. Each engine process opened the bundle first ({opened} s); their peak resident memory: "
        f"{', '.join(f'{x:.0f}' for x in c['peak_mb'])} MB. A run's processor time by size: {by_size}.",
        "",
        f"Scaled to the whole re-solve (each of a size's M days at that size's measured run): "
        f"**{cpu['total_s'] / 3600:.1f} CPU-hours**. With a core per engine process it finishes within its lead time of "
        f"{LEAD_S / 60:.0f} minutes on **{_needs(cpu)}**, at least {cpu['lower_bound']} even if runs could be split; "
        f"each process needs at most the {max(c['peak_mb']):,.0f} MB measured here. With runs as slow as the wall times "
        f"measured here ({c['workers']} processes sharing {res['cpus']} busy cores) it would take {_needs(wall)}; the "
        f"{c['workers']}-process cluster measured here would take about {wall['wall_on_cluster_s'] / 60:.0f} min.",
    ]  # fmt: skip


def write(res: dict[str, Any], performance: Path) -> None:
    """The section of the performance document."""
    lines = [
        "## Fleet sizing at metropolitan scale",
        "",
        stamp("python -m bench.bench_fleet_metro" + (" --smoke" if res["setup"]["scale"] < 1.0 else "")),
        "",
        f"The generated metropolitan city (`bench/metro.py`: {res['nodes']:,} nodes, {res['edges']:,} edges) read "
        "back from a bundle; a platform's demand around its centres, its registered tasks and fleet; the city's "
        "horizon (module docstring of `bench/bench_fleet_metro.py`).",
        "",
        *_day_lines(res),
        "",
        *_dense_lines(res),
        "",
        *_resolve_lines(res),
        "",
        "The raw numbers of the last run are in `docs/perf_fleet_metro.json`.",
    ]
    write_section("fleet-metro", "\n".join(lines), performance)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--smoke", action="store_true", help="a small city and fleet, 2 days, 2 runs on 1 worker")
    ap.add_argument("--days", type=int, default=None, help="days in one engine process (default 3)")
    ap.add_argument("--cluster-days", type=int, default=None, help="days per size on the cluster (default 1)")
    ap.add_argument("--workers", type=int, default=None, help="Dask engine processes (default 2)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs", help="where the JSON and PERFORMANCE.md go")
    ap.add_argument("--report-only", type=Path, metavar="JSON")
    args = ap.parse_args(argv)
    performance = args.out / "PERFORMANCE.md"
    if args.report_only:
        write(json.loads(args.report_only.read_text()), performance)
        return 0
    setup = SMOKE if args.smoke else FULL
    chosen = {"days": args.days, "cluster_days": args.cluster_days, "workers": args.workers}
    setup = dataclasses.replace(setup, **{k: v for k, v in chosen.items() if v is not None})
    with tempfile.TemporaryDirectory() as tmp:
        res = measure(setup, Path(tmp))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "perf_fleet_metro.json").write_text(json.dumps(res, indent=1) + "\n")
    write(res, performance)
    print(json.dumps({k: res[k] for k in ("resolve", "dense")}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
