"""Epoch latency under the load a platform makes: the dispatch core in-process, the service over HTTP, and a
floor beside them.

Scenarios are data (``SCENARIOS``); every run is seeded. The epochs come from ``bench.load.Platform``: taxis
continue from where their committed paths took them, riders wait until matched or their patience runs out
(new requests fill the list up to the scenario's count), new tasks are registered every epoch and stay open
until a taxi serves them, and demand lies around centres (the bundled cities: their own requests and POIs).
Epoch 0 is solved and committed untimed on every path, epochs 1..n are timed. Per epoch, in the same run:

* in-process: ``services.dispatch.decide`` with the default threads and with one (alternating which goes
  first); the two decisions are checked equal; the garbage collector set as the server sets its own
  (``bench.baseline.as_the_server``);
* floor: with scipy, one reverse search per rider bounded by the pickup radius, one full reverse tree per
  new task's POI, and the two assignments (instrumented and ordinary taxis x riders over the pickup times);
* HTTP: a real ``python -m app run`` (uvicorn; in-memory store with the fleet worker inside, a fleet solve
  requested after the first epoch; or Redis, without a worker) posting the same epochs (their decisions are
  checked equal to the in-process ones), with the peak resident memory of the API process and of the
  service's whole process tree read from /proc (``bench.rss``); each round trip is also set against the
  server's own solve of that epoch (its response's ``stats.solve_ms``): the HTTP path's cost epoch by epoch,
  which load that changes between the in-process and the HTTP runs does not move.

``limits`` is not a platform's load but the API's largest epoch: 2,000 riders and 5,000 taxis (half
instrumented) within 1 km of Chengdu's centre, drawn afresh every epoch, no tasks. The ``-heavy`` scenarios
are the heaviest load a platform posts: every taxi vacant every epoch, where its last path took it, and
riders' origins and destinations, POIs and taxis' first nodes drawn uniformly over the whole network
(``bench.load.SpreadDemand``), on the metropolitan city and on a street grid that takes 53 minutes to
cross, under ``step3_reach_above_s``, so that no reach applies there.

With ``--baseline DIR`` every timed epoch is also decided by the checkout at DIR (the previous code), in a
process of its own on the same inputs (``bench.baseline``), its decision checked equal: the same-run ratio.

    python -m bench.bench_epoch                           # every scenario, writes docs/PERFORMANCE.md
    python -m bench.bench_epoch --scenario paper --epochs 20 --no-http --no-write   # a quick look
    python -m bench.bench_epoch --baseline ../base      # beside the previous code (git worktree add ../base main)
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import functools
import hashlib
import json
import os
import resource
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as cg
from scipy.optimize import linear_sum_assignment

from bench import metro
from bench.baseline import Baseline, as_the_server
from bench.load import Centres, CentresDemand, Demand, Load, Platform, RecordedDemand, SpreadDemand
from bench.report import ROOT, machine, stamp, write_section
from bench.rss import TreePeak
from services.city import City
from services.citydata import CityMeta, city_from_network, haversine_m, save_bundle
from services.dispatch import decide, warm_up
from services.kernel.parallel import default_workers
from services.ledger import Ledger, apply_decision, ledger_view
from services.model import CountsView, Decision, Rider, RiderId, Snapshot, Task, Taxi, TaxiId
from services.network.network import build_network

PHASES = ("pickups", "trips", "step1", "step2", "step3", "algorithm2", "tasks")


@dataclass(frozen=True)
class Scenario:
    name: str
    city: str  # a bundled city, "grid" / "grid53" (generated street grids), "metro" (bench.metro's city)
    # or "metro-shuffled" (the same with its nodes in a random order, bench.metro.shuffled)
    load: Load
    epochs: int
    limits: bool = False  # the API's largest epoch, drawn afresh every epoch (no platform load)
    spread: bool = False  # demand, POIs and taxis spread over the whole network (else around centres)
    http: bool = True  # also over HTTP (a generated city the service can serve)


SCENARIOS = {
    "paper": Scenario("paper", "chengdu", Load(60, 60, 10, 40), 60),
    "city": Scenario("city", "manhattan", Load(600, 1400, 400, 40), 60),
    "metro100": Scenario("metro100", "grid", Load(1500, 3500, 800, 100), 10),
    "metro300": Scenario("metro300", "grid", Load(1500, 3500, 800, 300), 10),
    "metro250k": Scenario("metro250k", "metro", Load(1500, 3500, 800, 100), 10),
    "metro250k-heavy": Scenario(
        "metro250k-heavy", "metro", Load(1500, 3500, 800, 100, all_vacant=True), 10, spread=True
    ),
    "metro250k-shuffled": Scenario(
        "metro250k-shuffled", "metro-shuffled", Load(1500, 3500, 800, 100), 10, http=False
    ),
    "grid53-heavy": Scenario(
        "grid53-heavy", "grid53", Load(1500, 3500, 800, 100, all_vacant=True), 10, spread=True
    ),
    "limits": Scenario("limits", "chengdu", Load(2500, 2500, 2000, 0), 4, limits=True),
}
GENERATED = {"grid": "metrogrid", "grid53": "metrogrid53", "metro": "metro250k"}  # made here: their names

SHUFFLE_SEED = 7  # metro250k-shuffled's node order
GRID_SIDE = 150
GRID_BLOCK_M = 120.0
GRID53_BLOCK_M = 104.0  # 53 minutes across at 35 km/h: under step3_reach_above_s, so no reach applies
GRID_ORIGIN = (104.0, 30.55)  # lon, lat of the south-west corner


def grid_city(side: int = GRID_SIDE, block_m: float = GRID_BLOCK_M, name: str = GENERATED["grid"]) -> City:
    """A square street grid: ``side`` x ``side`` nodes ``block_m`` apart, two-way streets, default speed."""
    lon0, lat0 = GRID_ORIGIN
    ids = np.arange(side * side, dtype=np.int64)
    row, col = np.divmod(ids, side)
    lat = lat0 + row * block_m / 111_320.0
    lon = lon0 + col * block_m / (111_320.0 * np.cos(np.radians(lat0)))
    right = ids[col < side - 1]
    up = ids[row < side - 1]
    u = np.concatenate([right, right + 1, up, up + side])
    v = np.concatenate([right + 1, right, up + side, up])
    length = haversine_m(lon[u], lat[u], lon[v], lat[v])
    network = build_network(ids, lon, lat, u, v, length, None, 35.0)
    return city_from_network(network, CityMeta(name=name, timezone="Asia/Shanghai", source="generated"))


def load_city(sc: Scenario) -> City:
    if sc.city == "grid":
        return grid_city()
    if sc.city == "grid53":
        return grid_city(block_m=GRID53_BLOCK_M, name=GENERATED["grid53"])
    if sc.city == "metro":
        return metro.metro_city()
    if sc.city == "metro-shuffled":
        return metro.shuffled(metro.metro_city(), SHUFFLE_SEED)[0]
    from app.runs.workload import open_bundle

    return open_bundle(ROOT / "app" / "data" / "cities" / sc.city).city


def demand(sc: Scenario, city: City) -> Demand:
    """Where the scenario's trips, POIs and taxis are (module docstring)."""
    if sc.spread:
        return SpreadDemand(city)
    if sc.city in ("metro", "metro-shuffled"):
        xy, weight = metro.centre_layout(city)
        return CentresDemand(city, Centres(city, xy, weight, 2_500.0))
    if sc.city == "grid":
        return CentresDemand(city, Centres.on_bbox(city, 2_000.0), trip_median_m=3_000.0, trip_max_m=12_000.0)
    from app.runs.spec import RunSpec
    from app.runs.workload import demand_for, open_bundle

    bundle = open_bundle(ROOT / "app" / "data" / "cities" / sc.city)
    day = demand_for(RunSpec(city=sc.city, n1=sc.load.n_instrumented, n0=sc.load.n_ordinary), bundle)
    origins = np.array([r.origin for r in day.requests], dtype=np.int64)
    dests = np.array([r.destination for r in day.requests], dtype=np.int64)
    return RecordedDemand(origins, dests, bundle.candidates)


def limits_epochs(city: City, sc: Scenario, n: int) -> Iterator[tuple[Snapshot, list[Task]]]:
    """The API's largest epochs: every taxi and rider origin at random nodes within 1 km of the median node
    position, riders requested 0-300 s earlier, drawn afresh each epoch, 200 s apart from 08:00 local."""
    rng = np.random.default_rng(sc.load.seed)
    t0 = dt.datetime(2026, 11, 23, 8, 0, tzinfo=ZoneInfo(city.horizon.timezone)).timestamp()
    net = city.network
    near = np.flatnonzero(np.hypot(net.x_m - np.median(net.x_m), net.y_m - np.median(net.y_m)) <= 1000.0)
    ld = sc.load
    for e in range(n):
        now = t0 + e * city.horizon.epoch_s
        pick = near[rng.integers(len(near), size=ld.riders + ld.n_instrumented + ld.n_ordinary)]
        dest = rng.integers(net.n_nodes, size=ld.riders)
        riders = tuple(
            Rider(RiderId(f"r{e}-{i}"), int(pick[i]), int(dest[i]), now - float(rng.uniform(0, 300)))
            for i in range(ld.riders)
        )
        taxis = tuple(
            Taxi(TaxiId(f"i{i}" if i < ld.n_instrumented else f"o{i}"), int(v), i < ld.n_instrumented, True)
            for i, v in enumerate(pick[ld.riders :].tolist())
        )
        yield Snapshot(f"e{e}", now, riders, taxis), []


class Epochs:
    """The scenario's epochs, one at a time, fed back with each decision (the platform's load), or the
    limits' fresh draws."""

    def __init__(self, sc: Scenario, city: City) -> None:
        self.platform = None if sc.limits else Platform(city, sc.load, demand(sc, city))
        self._limits = limits_epochs(city, sc, 10**6) if sc.limits else None

    def next(self) -> tuple[Snapshot, list[Task]]:
        if self.platform is not None:
            return self.platform.next_epoch()
        assert self._limits is not None
        return next(self._limits)

    def apply(self, d: Decision) -> None:
        if self.platform is not None:
            self.platform.apply(d.rider_matches, d.task_assignments, d.expired_rider_ids)


def digest(d: Decision) -> str:
    """A decision's who-serves-whom, to check that two runs decided the same epochs."""
    pairs = sorted((str(m.taxi_id), str(m.rider_id), m.step, m.path) for m in d.rider_matches)
    routes = sorted((str(a.taxi_id), str(a.task_id), a.path) for a in d.task_assignments)
    return hashlib.sha256(repr((pairs, routes, sorted(d.expired_rider_ids))).encode()).hexdigest()[:16]


def floor_once(city: City, snap: Snapshot, new_nodes: list[int]) -> float:
    """The floor: bounded reverse searches from the riders, full reverse trees from the new tasks' POIs, the
    two assignments; timed."""
    net = city.network
    reverse = sp.csr_matrix((net.edge_time_s, (net.edge_v, net.edge_u)), shape=(net.n_nodes, net.n_nodes))
    speed = float((net.edge_length_m / net.edge_time_s).min())
    origins = np.array([r.origin for r in snap.riders], dtype=np.int64)
    vacant = [t for t in snap.taxis if t.vacant]
    taxis = np.array([t.node for t in vacant], dtype=np.int64)
    instr = np.array([t.instrumented for t in vacant], dtype=bool)
    started = time.perf_counter()
    if len(origins) and len(taxis):
        pick = cg.dijkstra(reverse, indices=origins, limit=city.params.radius_m / speed)[:, taxis]
        for cols in (instr, ~instr):
            m = pick[:, cols]
            if m.size:
                linear_sum_assignment(np.where(np.isfinite(m), m, 1e9))
    if new_nodes:
        cg.dijkstra(reverse, indices=np.array(new_nodes, dtype=np.int64))
    return time.perf_counter() - started


def _lap(marks: list[tuple[str, float]], name: str) -> None:
    marks.append((name, time.perf_counter()))


def _timed(
    city: City, view: CountsView, snap: Snapshot, tasks: list[Task], workers: int
) -> tuple[float, Decision, dict[str, float]]:
    """One ``decide``: its time, the decision and the milliseconds of each phase."""
    marks: list[tuple[str, float]] = []
    started = time.perf_counter()
    d = decide(city, view, snap, tasks, workers=workers, phase=functools.partial(_lap, marks))
    took = time.perf_counter() - started
    split: dict[str, float] = {}
    last = started
    for p, at in marks:
        split[p] = split.get(p, 0.0) + (at - last) * 1000.0
        last = at
    return took, d, split


def run_inprocess(sc: Scenario, n: int, baseline: Path | None = None) -> dict[str, Any]:
    """The scenario's epochs in-process, on the default threads and on one, beside the floor (and the
    ``baseline`` checkout's ``decide``, on the default threads, in a process of its own)."""
    city = load_city(sc)
    workers = default_workers()
    ledger = Ledger()  # what the store would hold: the committed counts and tasks
    epochs = Epochs(sc, city)
    lat, lat1, lat_b, flo, phases, open_n, free_n, digests = [], [], [], [], [], [], [], []
    base = Baseline(baseline, city) if baseline is not None else None
    warm_up(city)  # every kernel compiled (or loaded from the cache) outside timing, as the server does
    as_the_server()  # and its garbage collector
    for e in range(n + 1):
        snap, tasks = epochs.next()
        ledger.tasks.update({t.id: t for t in tasks})
        task_list = list(ledger.tasks.values())
        view = ledger_view(ledger, (t.id for t in snap.taxis if t.instrumented), city.grid.n_cells)
        if e == 0:  # untimed, as over HTTP, where the server's first epoch may still compile kernels
            d = decide(city, view, snap, task_list, workers=workers)
        else:
            out = {
                w: _timed(city, view, snap, task_list, w) for w in ((workers, 1) if e % 2 else (1, workers))
            }
            if out[workers][1] != out[1][1]:
                raise AssertionError(f"epoch {e}: the decision depends on the number of threads")
            d = out[workers][1]
            lat.append(out[workers][0])
            lat1.append(out[1][0])
            phases.append(out[workers][2])
            open_n.append(int(d.stats["open_tasks"]))
            free_n.append(int(d.stats["vacant_instrumented"]) - int(d.stats["step1_matches"]))
            flo.append(floor_once(city, snap, [t.node for t in tasks]))
            was = ""
            if base is not None:
                took_b, d_b = base.decide(view, snap, task_list, workers)
                if digest(d_b) != digest(d):
                    raise AssertionError(f"epoch {e}: the baseline decided otherwise")
                lat_b.append(took_b)
                was = f", baseline {took_b * 1000:.0f} ms"
            print(
                f"  [{sc.name}] epoch {e}: {lat[-1] * 1000:.0f} ms ({lat1[-1] * 1000:.0f} on one thread), "
                f"floor {flo[-1] * 1000:.0f} ms{was}, {open_n[-1]} open tasks, {free_n[-1]} taxis for Step 3",
                flush=True,
            )
        digests.append(digest(d))
        apply_decision(ledger, d.visits, d.task_updates)
        epochs.apply(d)
    if base is not None:
        base.close()
    return {
        "latency": lat,
        "latency_1thread": lat1,
        "latency_baseline": lat_b,
        "baseline": base.origin if base is not None else None,
        "floor": flo,
        "phases_ms": {p: float(np.median([x.get(p, 0.0) for x in phases])) for p in PHASES},
        "open_tasks_median": float(np.median(open_n)),
        "step3_taxis_median": float(np.median(free_n)),
        "workers": workers,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "digests": digests,
        "city_size": (city.network.n_nodes, city.network.n_edges),
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _iso(city: City, t: float) -> str:
    return dt.datetime.fromtimestamp(t, tz=ZoneInfo(city.horizon.timezone)).isoformat()


def task_docs(city: City, tasks: list[Task]) -> list[dict[str, Any]]:
    """New tasks as the platform registers them (``POST .../tasks``): external node ids, local times."""
    ids = city.network.node_ids
    return [
        {"id": t.id, "location": {"node": int(ids[t.node])}, "scheduled_at": _iso(city, t.scheduled_at_s)}
        for t in tasks
    ]


def _epoch_body(city: City, snap: Snapshot) -> str:
    ids = city.network.node_ids
    return json.dumps(
        {
            "epoch_id": snap.epoch_id,
            "time": _iso(city, snap.time_s),
            "riders": [
                {
                    "id": r.id,
                    "origin": {"node": int(ids[r.origin])},
                    "destination": {"node": int(ids[r.destination])},
                    "requested_at": _iso(city, r.requested_at_s),
                }
                for r in snap.riders
            ],
            "taxis": [
                {
                    "id": t.id,
                    "location": {"node": int(ids[t.node])},
                    "instrumented": t.instrumented,
                    "status": "vacant" if t.vacant else "busy",
                }
                for t in snap.taxis
            ],
        }
    )


def _wait_ready(client: Any, proc: subprocess.Popen[bytes]) -> float:
    """Wait for ``/readyz`` (the warm-up compiles when numba's cache is cold); seconds it took."""
    import httpx

    started = time.monotonic()
    while True:
        try:
            if client.get("/readyz").status_code == 200:
                return time.monotonic() - started
        except httpx.TransportError:
            pass
        if proc.poll() is not None:
            raise RuntimeError("the service exited before it was ready")
        if time.monotonic() - started > 900.0:
            raise RuntimeError("the service did not become ready")
        time.sleep(0.1)


@dataclass
class _Service:
    """A running ``python -m app run`` of the benchmark: its process, client and the city's name there."""

    proc: subprocess.Popen[bytes]
    client: Any  # httpx.Client with the token
    name: str
    ready_s: float


@contextlib.contextmanager
def _service(
    sc: Scenario, city: City, redis_url: str | None, worker: bool, port: int | None, root: Path = ROOT
) -> Iterator[_Service]:
    """The real service (uvicorn; in-memory store, or Redis at ``redis_url`` under a fresh key prefix,
    deleted afterwards), ready; stopped with its whole process group on the way out. With ``worker`` the
    fleet worker runs inside it as ``make run`` runs it (its simulation runs on child processes), with a
    fresh run cache. ``root``: the checkout whose service runs (another one: the previous code)."""
    import httpx

    port = port or _free_port()
    token = "bench-token-0123456789"
    prefix = f"bench{os.getpid()}x{port}"
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "SD_PORT": str(port),
            "SD_VAR_DIR": str(Path(tmp) / "var"),
            "PYTHONPATH": str(root),
        }
        env["SD_TOKENS"] = json.dumps({token: ["read", "dispatch", "admin"]})
        env["SD_WORKER_EMBEDDED"] = "on" if worker else "off"
        if redis_url is not None:
            env.update({"SD_STORE": "redis", "SD_REDIS_URL": redis_url, "SD_REDIS_PREFIX": prefix})
        name = sc.city
        if sc.city in GENERATED:
            name = GENERATED[sc.city]
            save_bundle(Path(tmp) / name, city.network, CityMeta(name=name, timezone=city.horizon.timezone))
            env["SD_CITIES_DIR"] = tmp
        started = time.monotonic()
        proc = subprocess.Popen(
            [sys.executable, "-m", "app", "run"],
            env=env,
            cwd=root,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # its own process group: the worker's processes stop with it
        )
        try:
            with httpx.Client(
                base_url=f"http://127.0.0.1:{port}",
                timeout=600.0,
                headers={"Authorization": f"Bearer {token}"},
            ) as client:
                _wait_ready(client, proc)
                yield _Service(proc, client, name, time.monotonic() - started)
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, 9)
                proc.wait()
            if redis_url is not None:
                import redis

                keys = redis.Redis.from_url(redis_url)
                for key in keys.scan_iter(match=f"{prefix}:*", count=1000):
                    keys.delete(key)
                keys.close()


def _post_epoch(svc: _Service, city: City, snap: Snapshot, tasks: list[Task]) -> tuple[float, dict[str, Any]]:
    """Register the epoch's new tasks, post the epoch; the round trip's seconds and the response."""
    if tasks:
        svc.client.post(f"/v1/cities/{svc.name}/tasks", json=task_docs(city, tasks)).raise_for_status()
    body = _epoch_body(city, snap)
    t0 = time.perf_counter()
    r = svc.client.post(
        f"/v1/cities/{svc.name}/epochs", content=body, headers={"Content-Type": "application/json"}
    )
    took = time.perf_counter() - t0
    r.raise_for_status()
    return took, dict(r.json())


WORKER_WAIT_S = 60.0
"""How long after the last epoch the memory of the service is still sampled while its worker solves."""


BUNDLED_CITY = "chengdu"
"""The bundled city whose fleet solve runs beside the epochs of a city that cannot be sized."""


def _request_solve(svc: _Service, city: str) -> bool:
    """Ask the service's worker for a fleet solve of ``city``: ``True`` when accepted, ``False`` when the
    city has too little recorded history to be sized (409 ``insufficient_history``: no run starts)."""
    r = svc.client.post(f"/v1/cities/{city}/fleet/solve")
    if r.status_code == 409 and r.json().get("error") == "insufficient_history":
        return False
    r.raise_for_status()
    return True


def _solve_over(svc: _Service, city: str) -> bool:
    """Whether the worker has no solve of ``city`` running or pending."""
    st = svc.client.get(f"/v1/cities/{city}/fleet/status").json()
    return st.get("solving") is None and st.get("pending_request") is None


def run_http(
    sc: Scenario,
    n: int,
    redis_url: str | None = None,
    worker: bool = True,
    port: int | None = None,
    worker_wait_s: float = WORKER_WAIT_S,
    root: Path = ROOT,
) -> dict[str, Any]:
    """Post the scenario's epochs to the real service over HTTP (``_service``), sampling the resident memory
    of the API process and of the service's whole process tree (``bench.rss``). With ``worker``, a fleet
    solve of the city is requested after the untimed first epoch (of ``BUNDLED_CITY`` when the city has too
    little history to be sized), so that the timed epochs run beside the worker's simulation runs as on a
    platform at the top of an hour; its memory is sampled until that solve is over, for at most
    ``worker_wait_s`` after the last epoch. ``root``: the checkout whose service runs."""
    from app.usecases.epoch_record import decision_of

    city = load_city(sc)
    epochs = Epochs(sc, city)
    lat: list[float] = []
    solve: list[float] = []  # the server's own solve time of each epoch (its response's stats.solve_ms)
    digests: list[str] = []
    solving = False  # a fleet solve was accepted (a city without its M days of history gets none)
    sized = ""  # the city the worker solves beside the epochs
    with _service(sc, city, redis_url, worker, port, root) as svc, TreePeak(svc.proc.pid) as peak:
        for e in range(n + 1):
            snap, tasks = epochs.next()
            took, doc = _post_epoch(svc, city, snap, tasks)
            d = decision_of(city, doc)
            expired = tuple(RiderId(x) for x in doc["expired_rider_ids"])
            digests.append(digest(_with_expired(d, expired)))
            if epochs.platform is not None:
                epochs.platform.apply(d.rider_matches, d.task_assignments, expired)
            if e == 0 and worker:
                sized = svc.name
                solving = _request_solve(svc, sized)
                if not solving:  # refused for too little history: a bundled city is sized beside the epochs
                    sized = BUNDLED_CITY
                    solving = _request_solve(svc, sized)
            if e > 0:  # the server's first epoch may still compile kernels: epochs 1..n are timed
                lat.append(took)
                solve.append(float(doc["stats"]["solve_ms"]) / 1000.0)
                print(
                    f"  [{sc.name}] HTTP epoch {e}: {took * 1000:.0f} ms (server solve {solve[-1] * 1000:.0f})",
                    flush=True,
                )
        waited = time.monotonic()
        while solving and not _solve_over(svc, sized) and time.monotonic() - waited < worker_wait_s:
            time.sleep(1.0)
        solve_over = not solving or _solve_over(svc, sized)
        ready_s = svc.ready_s
    print(
        f"  [{sc.name}] peak: API RSS {peak.process_mb:.0f} MB, service PSS {peak.tree_mb:.0f} MB"
        f" (RSS sum {peak.tree_rss_mb:.0f} MB)",
        flush=True,
    )
    return {
        "latency": lat,
        "server_solve": solve,
        "server_peak_rss_mb": peak.process_mb,
        "service_peak_pss_mb": peak.tree_mb,
        "service_peak_rss_sum_mb": peak.tree_rss_mb,
        "worker": worker,
        "worker_solve_over": solve_over,
        "worker_solved": solving,
        "worker_city": sized,
        "digests": digests,
        "ready_s": ready_s,
    }


def run_http_paired(sc: Scenario, n: int, redis_url: str | None, roots: list[Path]) -> list[dict[str, Any]]:
    """The scenario's epochs posted to the services of several checkouts at once (``roots``; on Redis,
    each under its own key prefix, or on the in-memory store; no worker), each epoch to every one of them in turn, the first poster
    changing from epoch to epoch, so that load on the machine weighs on every one alike; their decisions
    are checked equal epoch by epoch. One ``run_http``-like result per checkout."""
    from app.usecases.epoch_record import decision_of

    city = load_city(sc)
    epochs = Epochs(sc, city)
    out: list[dict[str, Any]] = [{"latency": [], "server_solve": []} for _ in roots]
    with contextlib.ExitStack() as stack:
        services = [stack.enter_context(_service(sc, city, redis_url, False, None, root)) for root in roots]
        peaks = [stack.enter_context(TreePeak(svc.proc.pid)) for svc in services]
        for e in range(n + 1):
            snap, tasks = epochs.next()
            order = list(range(len(roots)))
            order = order[e % len(order) :] + order[: e % len(order)]
            docs: dict[int, dict[str, Any]] = {}
            for i in order:
                took, docs[i] = _post_epoch(services[i], city, snap, tasks)
                if e > 0:
                    out[i]["latency"].append(took)
                    out[i]["server_solve"].append(float(docs[i]["stats"]["solve_ms"]) / 1000.0)
            d = decision_of(city, docs[0])
            expired = tuple(RiderId(x) for x in docs[0]["expired_rider_ids"])
            want = digest(_with_expired(d, expired))
            for i, doc in docs.items():
                got = digest(
                    _with_expired(decision_of(city, doc), tuple(RiderId(x) for x in doc["expired_rider_ids"]))
                )
                if got != want:
                    raise AssertionError(
                        f"{sc.name} epoch {e}: the services of {roots[0]} and {roots[i]} differ"
                    )
            if epochs.platform is not None:
                epochs.platform.apply(d.rider_matches, d.task_assignments, expired)
            if e > 0:
                print(
                    f"  [{sc.name}] HTTP epoch {e}: "
                    + ", ".join(
                        f"{o['latency'][-1] * 1000:.0f} ms (solve {o['server_solve'][-1] * 1000:.0f})"
                        for o in out
                    ),
                    flush=True,
                )
    for o, peak in zip(out, peaks, strict=True):
        o["server_peak_rss_mb"] = peak.process_mb
    return out


def _with_expired(d: Any, expired: tuple[RiderId, ...]) -> Decision:
    """``d`` (a stored decision read back from a response) as a ``Decision`` for ``digest``."""
    return Decision(
        epoch_id="",
        time_s=0.0,
        rider_matches=d.rider_matches,
        task_assignments=d.task_assignments,
        tasks_completed=(),
        task_updates=(),
        unmatched_rider_ids=(),
        expired_rider_ids=expired,
        visits=(),
        intervals_touched=(),
        stats={},
    )


def over_solve(h: dict[str, Any]) -> tuple[dict[str, float], float]:
    """The HTTP path's own cost, epoch by epoch: the round trip minus the server's solve of that epoch (load
    that changes between the in-process and the HTTP runs cancels out), and its median as a percentage."""
    lat, solve = np.array(h["latency"]), np.array(h["server_solve"])
    return summary(list(lat - solve)), float(np.median(lat / solve - 1.0) * 100.0)


def summary(xs: list[float]) -> dict[str, float]:
    a = np.array(xs) * 1000.0
    return {
        "n": len(a),
        "p50_ms": float(np.median(a)),
        "p99_ms": float(np.percentile(a, 99)),
        "min_ms": float(a.min()),
        "max_ms": float(a.max()),
        "iqr_ms": float(np.subtract(*np.percentile(a, [75, 25]))),
    }


def measure(
    sc: Scenario,
    n: int,
    http: bool,
    baseline: Path | None = None,
    worker: bool = True,
    port: int | None = None,
) -> dict[str, Any]:
    """One scenario in-process (and over HTTP, and beside ``baseline``): the figures the report reads."""
    print(f"[{sc.name}] in-process, {n} epochs ...", flush=True)
    load_before = os.getloadavg()
    r = run_inprocess(sc, n, baseline)
    res: dict[str, Any] = {
        "scenario": asdict(sc),
        "machine": machine(),
        "city_size": r["city_size"],
        "workers": r["workers"],
        "inprocess": summary(r["latency"]),
        "inprocess_1thread": summary(r["latency_1thread"]),
        "floor": summary(r["floor"]),
        "phases_ms": r["phases_ms"],
        "open_tasks_median": r["open_tasks_median"],
        "step3_taxis_median": r["step3_taxis_median"],
        "bench_peak_rss_mb": r["peak_rss_mb"],
    }
    if r["latency_baseline"]:
        res["baseline"] = summary(r["latency_baseline"])
        res["baseline_origin"] = r["baseline"]
        res["over_baseline"] = float(np.median(np.array(r["latency"]) / np.array(r["latency_baseline"])))
    if http and sc.http:
        print(f"[{sc.name}] over HTTP, {n} epochs ...", flush=True)
        h = run_http(sc, n, worker=worker, port=port)
        if h["digests"] != r["digests"]:
            raise AssertionError(f"{sc.name}: the service decided other epochs than the core in-process")
        res["http"] = summary(h["latency"])
        res["http_minus_solve"], res["http_over_solve_pct"] = over_solve(h)
        for key in (
            "server_peak_rss_mb",
            "service_peak_pss_mb",
            "service_peak_rss_sum_mb",
            "worker",
            "worker_solve_over",
            "worker_solved",
            "worker_city",
        ):
            res[key] = h[key]
        res["ready_s"] = h["ready_s"]
    res["load_average"] = {"before": list(load_before), "after": list(os.getloadavg())}
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", choices=sorted(SCENARIOS), action="append")
    ap.add_argument("--epochs", type=int, default=None, help="override the scenarios' epoch counts")
    ap.add_argument("--no-http", action="store_true")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument(
        "--no-worker", action="store_true", help="HTTP: leave the fleet worker out of the service (no solve)"
    )
    ap.add_argument("--port", type=int, help="HTTP: the service's port (default: a free one)")
    ap.add_argument("--report-only", type=Path, metavar="JSON", help="rewrite the report from saved results")
    ap.add_argument(
        "--baseline",
        type=Path,
        metavar="DIR",
        help="also time the decide of the checkout at DIR (the previous code) on the same epochs, in-process",
    )
    ap.add_argument(
        "--redis-url",
        metavar="URL",
        help="instead: the HTTP path only, with the service on Redis at URL (its own section of the report)",
    )
    ap.add_argument(
        "--memory-pair",
        action="store_true",
        help="instead: the HTTP path only, on the in-memory store, beside --baseline's service (printed)",
    )
    args = ap.parse_args(argv)
    if args.memory_pair:
        if args.baseline is None:
            ap.error("--memory-pair needs --baseline")
        for name in args.scenario or ["paper", "city"]:
            sc = SCENARIOS[name]
            pair = run_http_paired(sc, args.epochs or sc.epochs, None, [ROOT, args.baseline.resolve()])
            for label, h in zip(("this code", "previous code"), pair, strict=True):
                extra, pct = over_solve(h)
                print(
                    f"  {name} ({label}), memory: round trip - solve {extra['p50_ms']:.1f} ms, {pct:+.1f} %, "
                    f"API process peak RSS {h['server_peak_rss_mb']:.0f} MB"
                )
        return 0
    if args.report_only:
        write_report(json.loads(args.report_only.read_text()))
        return 0
    if args.redis_url:
        return _redis_main(
            args.redis_url,
            args.scenario or ["paper", "city", "metro250k"],
            args.epochs,
            not args.no_write,
            args.port,
            args.baseline,
        )
    results: dict[str, dict[str, Any]] = {}
    for name in args.scenario or list(SCENARIOS):
        sc = SCENARIOS[name]
        results[name] = measure(
            sc, args.epochs or sc.epochs, not args.no_http, args.baseline, not args.no_worker, args.port
        )
        print(json.dumps(results[name], indent=1), flush=True)
        (ROOT / "bench" / "out").mkdir(exist_ok=True)
        (ROOT / "bench" / "out" / "last_epoch_results.json").write_text(json.dumps(results, indent=1))
    if not args.no_write:
        write_report(results)
    return 0


def _redis_main(
    url: str,
    names: list[str],
    epochs: int | None,
    write: bool,
    port: int | None = None,
    baseline: Path | None = None,
) -> int:
    """The HTTP path with the service on Redis, against the server's own solve of each epoch (and beside the
    ``baseline`` checkout's service, every epoch posted to both: ``run_http_paired``)."""
    rows = []
    for name in names:
        sc = SCENARIOS[name]
        n = epochs or sc.epochs
        runs = [("this code", ROOT)] + ([] if baseline is None else [("previous code", baseline.resolve())])
        print(
            f"[{name}] over HTTP on Redis ({', '.join(label for label, _ in runs)}), {n} epochs ...",
            flush=True,
        )
        if baseline is None:
            results = [run_http(sc, n, redis_url=url, worker=False, port=port)]
        else:
            results = run_http_paired(sc, n, url, [root for _, root in runs])
        for (label, _), h in zip(runs, results, strict=True):
            rows.append((name, label, n, summary(h["latency"]), *over_solve(h), h["server_peak_rss_mb"]))
            print(
                f"  {name} ({label}): round trip p50 {rows[-1][3]['p50_ms']:.0f} ms, over the solve "
                f"{rows[-1][5]:+.1f} %, {rows[-1][4]['p50_ms']:.1f} ms",
                flush=True,
            )
    if write:
        _write_redis(url, rows, baseline)
    return 0


def _write_redis(url: str, rows: list[tuple[Any, ...]], baseline: Path | None) -> None:
    """The section ``epoch-redis`` of the report."""
    how = "" if baseline is None else f" --baseline {baseline}"
    lines = [
        "## Epoch latency on Redis",
        "",
        stamp(f"python -m bench.bench_epoch --redis-url {url}{how}"),
        "",
        "The HTTP path of `Epoch latency`'s scenarios (the same epochs) with the service on Redis",
        "(`SD_STORE=redis`, a local redis-server, a fresh key prefix), as a deployment runs it: the round",
        "trip, and the round trip minus the server's own solve of the same epoch (`stats.solve_ms`), which is",
        "the cost of validation, the state load and the commit on Redis, and the response (target: at most",
        "+15 % over the solve). With `--baseline DIR` the service of the checkout at DIR (the previous code)",
        "runs beside it under its own key prefix and every epoch is posted to both in turn (the first poster",
        "alternating), decisions checked equal: load on the machine weighs on both alike.",
        "",
        "| scale | code | epochs | HTTP p50 ms | HTTP p99 ms | round trip - solve, p50 / p99 ms | over the solve (median) | server peak RSS MB |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, label, n, lat_s, extra, pct, rss in rows:
        lines.append(
            f"| {name} | {label} | {n} | {lat_s['p50_ms']:.1f} | {lat_s['p99_ms']:.1f} | "
            f"{extra['p50_ms']:.1f} / {extra['p99_ms']:.1f} | {pct:+.1f} % | {rss:.0f} |"
        )
    load = os.getloadavg()
    lines += [
        "",
        f"Load average (1/5/15 min) at the end of the run: {load[0]:.2f}/{load[1]:.2f}/{load[2]:.2f}.",
    ]
    write_section("epoch-redis", "\n".join(lines))


TARGETS: dict[str, dict[str, float]] = {  # p99 in ms; the HTTP p99 as a multiple of the floor's p99
    "paper": {"inprocess_ms": 60.0},
    "city": {"inprocess_ms": 300.0},
    "metro100": {"http_ms": 1000.0, "rss_mb": 1024.0},
    "metro300": {"http_ms": 1000.0, "rss_mb": 1024.0},
    "metro250k": {"http_ms": 1000.0, "http_floor_ratio": 2.0, "rss_mb": 1024.0, "ready_s": 30.0},
    "metro250k-heavy": {"inprocess_ms": 1500.0, "http_ms": 2000.0, "rss_mb": 1024.0},
    "grid53-heavy": {"http_floor_ratio": 2.0},
}


SERVICE_RSS_MB = 1536.0
"""The whole service's peak (the API process and the fleet worker's processes) where the API has an RSS target."""


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def _facts(name: str, r: dict[str, Any]) -> str:
    """One scenario's targets and where each stands."""
    t = TARGETS.get(name, {})
    facts = []
    ip = r["inprocess"]["p99_ms"]
    if "over_baseline" in r:
        facts.append(
            f"in-process {r['over_baseline']:.2f}x the previous code's time (median of per-epoch ratios)"
        )
    if "inprocess_ms" in t:
        facts.append(
            f"in-process p99 {ip:.0f} ms (target <= {t['inprocess_ms']:.0f}: {_verdict(ip <= t['inprocess_ms'])})"
        )
    if "http" in r:
        hp = r["http"]["p99_ms"]
        if "http_ms" in t:
            facts.append(
                f"HTTP p99 {hp:.0f} ms (target <= {t['http_ms']:.0f}: {_verdict(hp <= t['http_ms'])})"
            )
        ratio = hp / r["floor"]["p99_ms"]
        if "http_floor_ratio" in t:
            ok = ratio <= t["http_floor_ratio"]
            facts.append(
                f"= {ratio:.2f}x the floor's p99 (target <= {t['http_floor_ratio']:.0f}x: {_verdict(ok)})"
            )
        pct = r["http_over_solve_pct"]
        facts.append(
            f"HTTP round trip over the server's solve: median {pct:+.1f} % (target <= +15 %: {_verdict(pct <= 15)}), "
            f"{r['http_minus_solve']['p50_ms']:.1f} ms (p99 {r['http_minus_solve']['p99_ms']:.1f} ms)"
        )
        facts += _rss_facts(name, r, t)
        if "ready_s" in t:
            ok = r["ready_s"] <= t["ready_s"]
            facts.append(
                f"start-up to ready {r['ready_s']:.1f} s (target <= {t['ready_s']:.0f}: {_verdict(ok)})"
            )
    return f"- {name}: " + "; ".join(facts)


def _rss_facts(name: str, r: dict[str, Any], t: dict[str, float]) -> list[str]:
    """The API process's peak resident memory and the whole service's (children included), with targets."""

    def target(mb: float, limit: float | None) -> str:
        return "" if limit is None else f" (target <= {limit:.0f} MB: {_verdict(mb <= limit)})"

    api = r["server_peak_rss_mb"]
    facts = [f"API process peak RSS {api:.0f} MB{target(api, t.get('rss_mb'))}"]
    if "service_peak_pss_mb" in r:  # results of runs made before the service's peak was sampled lack it
        whole = r["service_peak_pss_mb"]
        solved = r.get("worker_city", "")
        if not r.get("worker"):
            how = "no fleet worker"
        elif not r.get("worker_solved", True):
            how = "the fleet worker inside, no solve requested"
        else:
            of = ""
            if solved == BUNDLED_CITY and SCENARIOS[name].city in GENERATED:
                of = f" of {solved} (this city has too little history to be sized)"
            how = f"with the fleet worker's solve{of}"
            if not r.get("worker_solve_over"):
                how += f", still running {WORKER_WAIT_S:.0f} s after the last epoch"
        limit = SERVICE_RSS_MB if "rss_mb" in t else None
        facts.append(
            f"the whole service's peak {whole:.0f} MB (the sum of its processes' PSS, {how}; their RSS sum"
            f" {r['service_peak_rss_sum_mb']:.0f} MB){target(whole, limit)}"
        )
    return facts


def _machines(results: dict[str, dict[str, Any]]) -> tuple[str | None, list[str]]:
    """The machine most of ``results`` were measured on (None: not recorded) and a line for each scenario
    measured on another one (a scenario rerun alone and merged with ``--report-only``)."""
    where = [r.get("machine") for r in results.values()]
    common = max(set(where), key=where.count) if where else None
    other = [
        f"{name} was measured on another machine: {r['machine']}."
        for name, r in results.items()
        if r.get("machine") not in (None, common)
    ]
    return common, other


def write_report(results: dict[str, dict[str, Any]]) -> None:
    common, other = _machines(results)
    lines = [
        "## Epoch latency",
        "",
        stamp("python -m bench.bench_epoch", common),
        *(["", *other] if other else []),
        "",
        "The load (`bench/bench_epoch.py` `SCENARIOS`, `bench/load.py`): taxis continue from where their",
        "committed paths took them; riders wait until matched or their patience (600 s) runs out, and new",
        "requests fill the waiting list up to the scenario's rider count each epoch; the scenario's new tasks are",
        "registered every epoch and stay open until a taxi serves them; epochs 200 s apart from 08:00 local, the",
        "first solved untimed on every path. paper and city: Chengdu's synthetic requests and OSM POIs, Manhattan's",
        "real requests; metro100 and metro300: a generated 150 x 150 street grid (22,500 nodes, 120 m blocks,",
        "35 km/h) with demand around four centres; metro250k: the generated metropolitan network of `bench/metro.py`",
        "(road hierarchy, one-way streets, a river crossed at 8 places; demand around its five centres), and",
        "metro250k-shuffled the same network with its nodes in a random order, as an OpenStreetMap extract",
        "numbers them (in-process only). The",
        "heaviest load (`-heavy`): every taxi vacant every epoch where its last path took it, riders' origins and",
        "destinations, POIs and taxis spread uniformly over the whole network; on metro250k, and on grid53, a",
        "150 x 150 grid of 104 m blocks that takes 53 minutes to cross, so no Step 3 reach applies. limits:",
        "the API's largest epoch (module docstring). In-process = `services.dispatch.decide` with the default",
        "threads and with one (decisions checked equal), the process's garbage collector set as the server sets",
        "its own (`app.api.warmup`: its thresholds, start-up's objects frozen); previous code = the same epochs",
        "decided by the checkout the run was given (`--baseline`), in its own process with the same collector,",
        "decisions checked equal; HTTP = a real",
        "`python -m app run` (uvicorn, in-memory store, the fleet worker inside it as `make run` runs it) posting",
        "the same epochs (decisions checked equal to the in-process ones), with a fleet solve of the city requested",
        f"after the untimed first epoch (of {BUNDLED_CITY} when the city has too little recorded history to be",
        "sized), so that the timed epochs run beside the worker's simulation processes as at the top of an hour;",
        "peak memory: the API process's high-water mark (VmHWM), and the largest sum of the proportional set",
        "sizes of the service's processes (the API and the worker's: a page shared by n processes counts 1/n in",
        "each, so every page the service holds counts once), with the largest sum of their RSS beside it (a",
        "shared library's pages count once per process there), sampled every 100 ms until the solve is over, at",
        f"most {WORKER_WAIT_S:.0f} s after the last epoch; `bench/rss.py`. Floor = with scipy, one",
        "reverse search per rider bounded by the pickup radius, one full reverse tree per new task's POI, and the",
        "two assignments over the pickup times, on the same epochs.",
        "",
        "| scale | nodes | taxis (instr.) | riders | new tasks | open tasks (median) | Step 3 taxis (median) | epochs | path | p50 ms | p99 ms | min-max ms | IQR ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    labels = {
        "inprocess": None,
        "inprocess_1thread": "in-process, 1 thread",
        "baseline": "in-process, previous code",
        "http": "HTTP",
        "floor": "floor",
    }
    for name, r in results.items():
        ld = r["scenario"]["load"]
        for how, label in labels.items():
            if how not in r:
                continue
            s = r[how]
            label = label or f"in-process, {r.get('workers', '?')} threads"
            lines.append(
                f"| {name} | {r['city_size'][0]:,} | {ld['n_instrumented'] + ld['n_ordinary']} ({ld['n_instrumented']}) | "
                f"{ld['riders']} | {ld['new_tasks']} | {r['open_tasks_median']:.0f} | {r['step3_taxis_median']:.0f} | "
                f"{s['n']} | {label} | {s['p50_ms']:.1f} | {s['p99_ms']:.1f} | {s['min_ms']:.1f}-{s['max_ms']:.1f} | {s['iqr_ms']:.1f} |"
            )
    lines += ["", "Targets and where each stands in this run:", ""]
    lines += [_facts(name, r) for name, r in results.items()]
    lines += ["", "Where the time goes (median ms per phase of `decide`, default threads):", ""]
    lines.append("| scale | " + " | ".join(PHASES) + " |")
    lines.append("|---|" + "---|" * len(PHASES))
    for name, r in results.items():
        ph = r.get("phases_ms", {})
        lines.append(f"| {name} | " + " | ".join(f"{ph.get(p, 0.0):.1f}" for p in PHASES) + " |")
    lines.append("")
    for name, r in results.items():
        if "load_average" in r:
            b, a = r["load_average"]["before"], r["load_average"]["after"]
            lines.append(
                f"- {name}: load average (1/5/15 min) {b[0]:.2f}/{b[1]:.2f}/{b[2]:.2f} before, {a[0]:.2f}/{a[1]:.2f}/{a[2]:.2f} after"
            )
    lines += ["", "The raw numbers of the last run are in `docs/perf_epoch.json`."]
    path = write_section("epoch", "\n".join(lines))
    (ROOT / "docs" / "perf_epoch.json").write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
