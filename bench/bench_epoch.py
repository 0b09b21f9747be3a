"""Epoch latency: the dispatch core in-process, the service over HTTP, and a tight floor beside them.

Scenarios are data (``SCENARIOS``); every run is seeded. Epoch 0 is solved and committed untimed on every path
(the server's may still compile kernels), epochs 1..n are timed. Per epoch, in the same run:

* in-process: ``services.dispatch.decide`` with the default threads and with one (alternating which goes
  first); the two decisions are checked equal;
* floor: the unavoidable work of the epoch, with scipy: one reverse search per rider origin bounded by the
  pickup radius, one full reverse tree per open POI, and the two assignments (instrumented and ordinary
  taxis x riders over the pickup times);
* HTTP: a real ``python -m app run`` (uvicorn, in-memory store) posting the same epochs, with the server's
  peak resident memory read from /proc; each round trip is also set against the server's own solve of that
  epoch (its response's ``stats.solve_ms``): the HTTP path's cost epoch by epoch, which load that changes
  between the in-process and the HTTP runs does not move.

The metropolitan scenarios run on a street grid generated here (150 x 150 nodes, 120 m blocks, two-way
streets at 35 km/h; no data file), with 5,000 taxis of which 1,500 instrumented, 800 riders and 100 or 300
open POI tasks per epoch; streets300 puts metro300 on a less regular generated network (``street_city``).

    python -m bench.bench_epoch                           # every scenario, writes docs/PERFORMANCE.md
    python -m bench.bench_epoch --scenario paper --epochs 20 --no-http --no-write   # a quick look
"""

from __future__ import annotations

import argparse
import datetime as dt
import functools
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

from bench.report import ROOT, stamp, write_section
from services.city import City
from services.citydata import CityMeta, city_from_network, haversine_m, load_city, save_bundle
from services.dispatch import decide, warm_up
from services.ledger import Ledger, apply_decision, ledger_view
from services.model import (
    Decision,
    Rider,
    RiderId,
    Snapshot,
    Task,
    TaskId,
    Taxi,
    TaxiId,
)
from services.network import build_network
from services.parallel import default_workers

BUNDLES = ROOT / "app" / "data" / "cities"
PHASES = ("pickups", "trips", "step1", "step2", "step3", "algorithm2", "tasks")


@dataclass(frozen=True)
class Scenario:
    name: str
    city: str  # a bundled city, or "grid" for the generated metropolitan street grid
    n_instrumented: int
    n_ordinary: int
    riders: float  # Poisson mean (paper, city) or exact count (grid)
    tasks: int  # up to this many new tasks per epoch (uniform, paper and city) or exactly this many (grid)
    epochs: int
    seed: int = 20261123
    disc_m: float | None = None  # taxis and riders' origins within this distance of the city's centre


SCENARIOS = {
    "paper": Scenario("paper", "chengdu", 60, 60, 10.0, 85, 60),
    "city": Scenario("city", "manhattan", 600, 1400, 400.0, 300, 60),
    "metro100": Scenario("metro100", "grid", 1500, 3500, 800, 100, 10),
    "metro300": Scenario("metro300", "grid", 1500, 3500, 800, 300, 10),
    "streets300": Scenario("streets300", "streets", 1500, 3500, 800, 300, 10),
    # the API's limits (SD_MAX_RIDERS, SD_MAX_TAXIS), everyone within reach of everyone
    "limits": Scenario("limits", "chengdu", 2500, 2500, 2000, 0, 4, disc_m=1000.0),
}
GENERATED = ("grid", "streets")  # cities made here, not bundled

GRID_SIDE = 150
GRID_BLOCK_M = 120.0
GRID_ORIGIN = (104.0, 30.55)  # lon, lat of the south-west corner


def grid_city(side: int = GRID_SIDE, block_m: float = GRID_BLOCK_M) -> City:
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
    return city_from_network(
        network, CityMeta(name="metrogrid", timezone="Asia/Shanghai", source="generated")
    )


def street_city(side: int = GRID_SIDE, block_m: float = GRID_BLOCK_M, seed: int = 7) -> City:
    """A street network less regular than ``grid_city``, as a real city is: the grid's nodes moved by up to
    ~25 m, 15 % of its blocks missing, a fifth of the side streets one-way, side streets at 25-40 km/h and
    every tenth row and column an arterial at 60 km/h, lengths 0-30 % longer than the straight line (bends);
    its largest strongly connected part (22,372 nodes, 70,293 directed edges, 6,471 of them one-way)."""
    rng = np.random.default_rng(seed)
    lon0, lat0 = GRID_ORIGIN
    ids = np.arange(side * side, dtype=np.int64)
    row, col = np.divmod(ids, side)
    shift = rng.normal(0.0, 25.0, (2, side * side))
    lat = lat0 + (row * block_m + shift[0]) / 111_320.0
    lon = lon0 + (col * block_m + shift[1]) / (111_320.0 * np.cos(np.radians(lat0)))
    right, up = ids[col < side - 1], ids[row < side - 1]
    a, b = np.concatenate([right, up]), np.concatenate([right + 1, up + side])
    arterial = np.concatenate([row[right] % 10 == 0, col[up] % 10 == 0])
    keep = arterial | (rng.random(len(a)) > 0.15)
    a, b, arterial = a[keep], b[keep], arterial[keep]
    one_way = ~arterial & (rng.random(len(a)) < 0.2)
    flip = rng.random(len(a)) < 0.5
    speed = np.where(arterial, 60.0, rng.choice([25.0, 30.0, 40.0], len(a)))
    tail, head = np.where(flip, b, a), np.where(flip, a, b)
    u = np.concatenate([tail, head[~one_way]])
    v = np.concatenate([head, tail[~one_way]])
    speed = np.concatenate([speed, speed[~one_way]])
    adj = sp.csr_matrix((np.ones(len(u)), (u, v)), shape=(side * side, side * side))
    _, part = cg.connected_components(adj, connection="strong")
    inside = part == np.argmax(np.bincount(part))
    e = inside[u] & inside[v]
    u, v, speed = u[e], v[e], speed[e]
    length = haversine_m(lon[u], lat[u], lon[v], lat[v]) * rng.uniform(1.0, 1.3, len(u))
    network = build_network(ids[inside], lon[inside], lat[inside], u, v, length, speed, 35.0)
    return city_from_network(
        network, CityMeta(name="metrostreets", timezone="Asia/Shanghai", source="generated")
    )


def load(sc: Scenario) -> City:
    if sc.city == "grid":
        return grid_city()
    if sc.city == "streets":
        return street_city()
    return load_city(BUNDLES / sc.city)


def epochs(city: City, sc: Scenario, n: int) -> Iterator[tuple[Snapshot, list[Task]]]:
    """Seeded epochs 200 s apart from 08:00 local: taxis at random nodes, riders requested 0-300 s
    earlier between random nodes, and the epoch's new tasks at random nodes (with ``disc_m``: taxis and
    riders' origins at random nodes that close to the median node position)."""
    rng = np.random.default_rng(sc.seed)
    tz = ZoneInfo(city.horizon.timezone)
    t0 = dt.datetime(2026, 11, 23, 8, 0, tzinfo=tz).timestamp()
    nn = city.network.n_nodes
    net = city.network
    near = np.arange(nn)
    if sc.disc_m is not None:
        off = np.hypot(net.x_m - np.median(net.x_m), net.y_m - np.median(net.y_m))
        near = np.flatnonzero(off <= sc.disc_m)
    exact = sc.city in GENERATED or sc.disc_m is not None
    for e in range(n):
        now = t0 + e * city.horizon.epoch_s
        nr = int(sc.riders) if exact else int(rng.poisson(sc.riders))
        riders = tuple(
            Rider(
                RiderId(f"r{e}-{i}"),
                int(near[rng.integers(len(near))]),
                int(rng.integers(nn)),
                now - float(rng.uniform(0, 300)),
            )
            for i in range(nr)
        )
        taxis = tuple(
            Taxi(TaxiId(f"i{i}"), int(near[rng.integers(len(near))]), True, True)
            for i in range(sc.n_instrumented)
        ) + tuple(
            Taxi(TaxiId(f"o{i}"), int(near[rng.integers(len(near))]), False, True)
            for i in range(sc.n_ordinary)
        )
        nt = sc.tasks if exact else int(rng.integers(0, sc.tasks + 1))
        tasks = [Task(TaskId(f"k{e}-{i}"), int(rng.integers(nn)), now - 60.0) for i in range(nt)]
        yield Snapshot(f"e{e}", now, riders, taxis), tasks


def floor_once(city: City, snap: Snapshot, open_nodes: list[int]) -> float:
    """The tight floor: bounded reverse searches from the riders, full reverse trees from the open POIs,
    the two assignments; timed."""
    net = city.network
    reverse = sp.csr_matrix((net.edge_time_s, (net.edge_v, net.edge_u)), shape=(net.n_nodes, net.n_nodes))
    speed = float((net.edge_length_m / net.edge_time_s).min())
    origins = np.array([r.origin for r in snap.riders], dtype=np.int64)
    taxis = np.array([t.node for t in snap.taxis], dtype=np.int64)
    instr = np.array([t.instrumented for t in snap.taxis], dtype=bool)
    started = time.perf_counter()
    if len(origins):
        pick = cg.dijkstra(reverse, indices=origins, limit=city.params.radius_m / speed)[:, taxis]
        for cols in (instr, ~instr):
            m = pick[:, cols]
            if m.size:
                linear_sum_assignment(np.where(np.isfinite(m), m, 1e9))
    if open_nodes:
        cg.dijkstra(reverse, indices=np.array(open_nodes, dtype=np.int64))
    return time.perf_counter() - started


def _lap(marks: list[tuple[str, float]], name: str) -> None:
    marks.append((name, time.perf_counter()))


def run_inprocess(sc: Scenario, n: int) -> dict[str, object]:
    city = load(sc)
    workers = default_workers()
    ledger = Ledger()  # what the store would hold: the committed counts and tasks
    lat, lat1, flo, phases, open_n = [], [], [], [], []
    warm_up(city)  # every kernel compiled (or loaded from the cache) outside timing, as the server does
    # epochs 1..n are timed, as over HTTP, where the server's first epoch is not (see ``run_http``)
    for e, (snap, tasks) in enumerate(epochs(city, sc, n + 1)):
        ledger.tasks.update({t.id: t for t in tasks})
        task_list = list(ledger.tasks.values())
        view = ledger_view(ledger, (t.id for t in snap.taxis if t.instrumented), city.grid.n_cells)
        if e == 0:
            d = decide(city, view, snap, task_list, workers=workers)
            apply_decision(ledger, d.visits, d.task_updates)
            continue
        out: dict[int, tuple[float, Decision, dict[str, float]]] = {}
        for w in (workers, 1) if e % 2 == 0 else (1, workers):
            marks: list[tuple[str, float]] = []
            stopwatch = functools.partial(_lap, marks)
            started = time.perf_counter()
            d = decide(city, view, snap, task_list, workers=w, phase=stopwatch)
            took = time.perf_counter() - started
            split: dict[str, float] = {}
            last = started
            for p, at in marks:
                split[p] = split.get(p, 0.0) + (at - last) * 1000.0
                last = at
            out[w] = (took, d, split)
        if out[workers][1] != out[1][1]:
            raise AssertionError(f"epoch {e}: the decision depends on the number of threads")
        d = out[workers][1]
        lat.append(out[workers][0])
        lat1.append(out[1][0])
        phases.append(out[workers][2])
        open_n.append(int(d.stats["open_tasks"]))
        flo.append(floor_once(city, snap, sorted({t.node for t in task_list if t.is_open(snap.time_s)})))
        apply_decision(ledger, d.visits, d.task_updates)
        print(
            f"  [{sc.name}] epoch {e}: {lat[-1] * 1000:.0f} ms ({lat1[-1] * 1000:.0f} on one thread), floor {flo[-1] * 1000:.0f} ms",
            flush=True,
        )
    return {
        "latency": lat,
        "latency_1thread": lat1,
        "floor": flo,
        "phases_ms": {p: float(np.median([x.get(p, 0.0) for x in phases])) for p in PHASES},
        "open_tasks_median": float(np.median(open_n)),
        "workers": workers,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _iso(city: City, t: float) -> str:
    return dt.datetime.fromtimestamp(t, tz=ZoneInfo(city.horizon.timezone)).isoformat()


def run_http(sc: Scenario, n: int, redis_url: str | None = None) -> dict[str, object]:
    """Start the real service (uvicorn; in-memory store, or Redis at ``redis_url`` under a fresh key
    prefix, deleted afterwards) and post the same epochs over HTTP."""
    import httpx

    city = load(sc)
    port = _free_port()
    token = "bench-token-0123456789"
    prefix = f"bench{os.getpid()}x{port}"
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "SD_PORT": str(port), "SD_TOKENS": json.dumps({token: ["read", "dispatch"]})}
        if redis_url is not None:
            env.update({"SD_STORE": "redis", "SD_REDIS_URL": redis_url, "SD_REDIS_PREFIX": prefix})
        name = sc.city
        if sc.city in GENERATED:
            name = city.name
            save_bundle(Path(tmp) / name, city.network, CityMeta(name=name, timezone=city.horizon.timezone))
            env["SD_CITIES_DIR"] = tmp
        proc = subprocess.Popen(
            [sys.executable, "-m", "app", "run"],
            env=env,
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        ids = city.network.node_ids
        lat: list[float] = []
        solve: list[float] = []  # the server's own solve time of each epoch (its response's stats.solve_ms)
        try:
            with httpx.Client(
                base_url=f"http://127.0.0.1:{port}",
                timeout=300.0,
                headers={"Authorization": f"Bearer {token}"},
            ) as client:
                ready_by = time.monotonic() + 900.0  # the warm-up compiles when numba's cache is cold
                while True:
                    try:
                        if client.get("/readyz").status_code == 200:
                            break
                    except httpx.TransportError:
                        pass
                    if time.monotonic() > ready_by:
                        raise RuntimeError("the service did not become ready")
                    time.sleep(0.1)
                for e, (snap, tasks) in enumerate(epochs(city, sc, n + 1)):
                    if tasks:
                        client.post(
                            f"/v1/cities/{name}/tasks",
                            json=[
                                {
                                    "id": t.id,
                                    "location": {"node": int(ids[t.node])},
                                    "scheduled_at": _iso(city, t.scheduled_at_s),
                                }
                                for t in tasks
                            ],
                        ).raise_for_status()
                    body = json.dumps(
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
                                    "status": "vacant",
                                }
                                for t in snap.taxis
                            ],
                        }
                    )
                    started = time.perf_counter()
                    r = client.post(
                        f"/v1/cities/{name}/epochs",
                        content=body,
                        headers={"Content-Type": "application/json"},
                    )
                    took = time.perf_counter() - started
                    r.raise_for_status()
                    if e > 0:  # the server's first epoch may still compile kernels: epochs 1..n are timed
                        lat.append(took)
                        solve.append(float(r.json()["stats"]["solve_ms"]) / 1000.0)
                        print(
                            f"  [{sc.name}] HTTP epoch {e}: {took * 1000:.0f} ms (server solve {solve[-1] * 1000:.0f})",
                            flush=True,
                        )
            status = Path(f"/proc/{proc.pid}/status").read_text()
            rss = int(status.split("VmHWM:")[1].split()[0]) / 1024.0
        finally:
            proc.terminate()
            proc.wait(timeout=30)
            if redis_url is not None:
                import redis

                keys = redis.Redis.from_url(redis_url)
                for key in keys.scan_iter(match=f"{prefix}:*", count=1000):
                    keys.delete(key)
                keys.close()
    return {"latency": lat, "server_solve": solve, "server_peak_rss_mb": rss}


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", choices=sorted(SCENARIOS), action="append")
    ap.add_argument("--epochs", type=int, default=None, help="override the scenarios' epoch counts")
    ap.add_argument("--no-http", action="store_true")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--report-only", type=Path, metavar="JSON", help="rewrite the report from saved results")
    ap.add_argument(
        "--redis-url",
        metavar="URL",
        help="instead: the HTTP path only, with the service on Redis at URL (its own section of the report)",
    )
    args = ap.parse_args(argv)
    if args.report_only:
        write_report(json.loads(args.report_only.read_text()))
        return 0
    if args.redis_url:
        return _redis_main(args.redis_url, args.scenario or ["paper", "city"], args.epochs, not args.no_write)
    results: dict[str, dict[str, object]] = {}
    for name in args.scenario or list(SCENARIOS):
        sc = SCENARIOS[name]
        n = args.epochs or sc.epochs
        print(f"[{name}] in-process, {n} epochs ...", flush=True)
        load_before = os.getloadavg()
        r = run_inprocess(sc, n)
        res: dict[str, object] = {
            "scenario": asdict(sc),
            "workers": r["workers"],
            "inprocess": summary(r["latency"]),  # type: ignore[arg-type]
            "inprocess_1thread": summary(r["latency_1thread"]),  # type: ignore[arg-type]
            "floor": summary(r["floor"]),  # type: ignore[arg-type]
            "phases_ms": r["phases_ms"],
            "open_tasks_median": r["open_tasks_median"],
            "bench_peak_rss_mb": r["peak_rss_mb"],
        }
        if not args.no_http:
            print(f"[{name}] over HTTP, {n} epochs ...", flush=True)
            h = run_http(sc, n)
            res["http"] = summary(h["latency"])  # type: ignore[arg-type]
            res["http_minus_solve"], res["http_over_solve_pct"] = over_solve(h)
            res["server_peak_rss_mb"] = h["server_peak_rss_mb"]
        res["load_average"] = {"before": list(load_before), "after": list(os.getloadavg())}
        results[name] = res
        print(json.dumps(res, indent=1), flush=True)
        (ROOT / "bench" / "out").mkdir(exist_ok=True)
        (ROOT / "bench" / "out" / "last_epoch_results.json").write_text(json.dumps(results, indent=1))
    if not args.no_write:
        write_report(results)
    return 0


def _redis_main(url: str, names: list[str], epochs: int | None, write: bool) -> int:
    """The HTTP path with the service on Redis, against the server's own solve of each epoch."""
    rows = []
    for name in names:
        sc = SCENARIOS[name]
        n = epochs or sc.epochs
        print(f"[{name}] over HTTP on Redis, {n} epochs ...", flush=True)
        h = run_http(sc, n, redis_url=url)
        rows.append((name, n, summary(h["latency"]), *over_solve(h)))  # type: ignore[arg-type]
        print(
            f"  {name}: round trip p50 {rows[-1][2]['p50_ms']:.0f} ms, over the solve {rows[-1][4]:+.1f} %",
            flush=True,
        )
    if write:
        lines = [
            "## Epoch latency on Redis",
            "",
            stamp(f"python -m bench.bench_epoch --redis-url {url}"),
            "",
            "The HTTP path of `Epoch latency`'s scenarios with the service on Redis (`SD_STORE=redis`, a local",
            "redis-server, a fresh key prefix), as a deployment runs it: the round trip, and the round trip minus",
            "the server's own solve of the same epoch (`stats.solve_ms`), which is the cost of validation, the",
            "state load and the commit on Redis, and the response.",
            "",
            "| scale | epochs | HTTP p50 ms | HTTP p99 ms | round trip - solve, p50 / p99 ms | over the solve (median) |",
            "|---|---|---|---|---|---|",
        ]
        for name, n, lat_s, extra, pct in rows:
            lines.append(
                f"| {name} | {n} | {lat_s['p50_ms']:.1f} | {lat_s['p99_ms']:.1f} | "
                f"{extra['p50_ms']:.1f} / {extra['p99_ms']:.1f} | {pct:+.1f} % |"
            )
        write_section("epoch-redis", "\n".join(lines))
    return 0


TARGETS = {  # issue 11: p99 in-process (ms), p99 over HTTP as a multiple of the floor's p99
    "paper": {"inprocess_ms": 60.0},
    "city": {"inprocess_ms": 300.0},
    "metro100": {"http_floor_ratio": 4.0, "rss_mb": 1024.0},
    "metro300": {"http_floor_ratio": 4.0, "rss_mb": 1024.0},
    "streets300": {"http_floor_ratio": 4.0, "rss_mb": 1024.0},  # metro300's target, off the grid
}


def write_report(results: dict[str, dict[str, Any]]) -> None:
    lines = [
        "## Epoch latency",
        "",
        stamp("python -m bench.bench_epoch"),
        "",
        "Inputs (seeded, `bench/bench_epoch.py` `SCENARIOS`): taxis at random nodes, riders requested 0-300 s",
        "earlier between random nodes, new tasks at random nodes every epoch (paper, city: 0..max; metro: exactly",
        "that many), epochs 200 s apart from 08:00 local, the first solved untimed on every path; counts and",
        "task states evolve as the decisions are committed. The metro scenarios run on a generated 150 x 150",
        "street grid (22,500 nodes, 89,400 directed edges, 120 m blocks) with 5,000 taxis (1,500 instrumented),",
        "800 riders and 100 or 300 new tasks an epoch;",
        "streets300 is metro300 on a less regular generated network (`street_city`: the grid's nodes moved,",
        "15 % of blocks missing, one-way side streets, 60 km/h arterials, bends; 22,372 nodes), as a city",
        "the service has not seen would be. limits is the largest epoch the API accepts (2,000 riders, 5,000",
        "taxis, half instrumented) on Chengdu with every taxi and every rider's origin within 1 km of the",
        "centre: about 3.5 million Step 1 candidate pairs, no tasks.",
        "In-process = `services.dispatch.decide` with the default threads and with one (the two decisions are",
        "checked equal on every epoch); HTTP = a real `python -m app run` (uvicorn, in-memory store), the",
        "client's round trip (also set against the server's own solve time of the same epoch, `stats.solve_ms`:",
        "the HTTP path's cost, unmoved by load that changes between the two runs); floor = with scipy, one",
        "reverse search per rider bounded by the pickup radius, one full reverse tree per open POI, and the two",
        "assignments over the pickup times, on the same epochs.",
        "",
        "| scale | taxis (instr.) | riders | open tasks (median) | epochs | path | p50 ms | p99 ms | min-max ms | IQR ms |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    labels = {
        "inprocess": None,
        "inprocess_1thread": "in-process, 1 thread",
        "http": "HTTP",
        "floor": "floor",
    }
    for name, r in results.items():
        sc = r["scenario"]
        for how, label in labels.items():
            if how not in r:
                continue
            s = r[how]
            label = label or f"in-process, {r.get('workers', '?')} threads"
            lines.append(
                f"| {name} | {sc['n_instrumented'] + sc['n_ordinary']} ({sc['n_instrumented']}) | {sc['riders']:.0f} | "
                f"{r.get('open_tasks_median', float('nan')):.0f} | {s['n']} | {label} | {s['p50_ms']:.1f} | "
                f"{s['p99_ms']:.1f} | {s['min_ms']:.1f}-{s['max_ms']:.1f} | {s['iqr_ms']:.1f} |"
            )
    lines += ["", "Targets (issue 11) and where each stands in this run:", ""]
    for name, r in results.items():
        t = TARGETS.get(name, {})
        facts = []
        ip = r["inprocess"]["p99_ms"]
        if "inprocess_ms" in t:
            facts.append(
                f"in-process p99 {ip:.0f} ms (target <= {t['inprocess_ms']:.0f}: {'met' if ip <= t['inprocess_ms'] else 'NOT met'})"
            )
        if "http" in r:
            hp = r["http"]["p99_ms"]
            ratio = hp / r["floor"]["p99_ms"]
            over = (r["http"]["p50_ms"] / r["inprocess"]["p50_ms"] - 1.0) * 100.0
            if "http_floor_ratio" in t:
                facts.append(
                    f"HTTP p99 {hp:.0f} ms = {ratio:.2f}x the floor's p99 (target <= {t['http_floor_ratio']:.0f}x: {'met' if ratio <= t['http_floor_ratio'] else 'NOT met'})"
                )
            facts.append(
                f"HTTP p50 over in-process p50: {over:+.0f}% (target <= 15%: {'met' if over <= 15 else 'NOT met'})"
            )
            if "http_over_solve_pct" in r:
                facts.append(
                    f"HTTP round trip over the server's solve of the same epoch: median {r['http_over_solve_pct']:+.1f}%, "
                    f"{r['http_minus_solve']['p50_ms']:.1f} ms (p99 {r['http_minus_solve']['p99_ms']:.1f} ms)"
                )
        if "server_peak_rss_mb" in r:
            rss = r["server_peak_rss_mb"]
            verdict = (
                f" (target <= {t['rss_mb']:.0f} MB: {'met' if rss <= t['rss_mb'] else 'NOT met'})"
                if "rss_mb" in t
                else ""
            )
            facts.append(f"server peak RSS {rss:.0f} MB{verdict}")
        lines.append(f"- {name}: " + "; ".join(facts))
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
