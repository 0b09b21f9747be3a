"""Fleet sizing of a city the platform brings, at a platform's scale, through the API of one
``python -m app run``: what an operator who imports their own road network goes through.

    python -m bench.bench_fleet_own_city                                   # 60 x 60 grid, 600 taxis, M = 10
    python -m bench.bench_fleet_own_city --side 10 --taxis 24 --days 2 --no-write   # a smoke run (a minute)

1. A network the project has never seen, written as CSV (``nodes.csv``: id,lon,lat; ``edges.csv``:
   u,v,length_m): a ``--side`` x ``--side`` street grid of 200 m blocks near 104.06 E, 30.66 N, node
   positions jittered by up to 30 m, node ids scattered (not 0..n-1), every 5th street one-way (alternating
   directions), 4 % of the other links missing (one direction or both), lengths the straight distance times
   1.0-1.15.
2. ``python -m app import-city`` with the horizon's defaults (08:00-12:00, 4 intervals) in Asia/Shanghai and
   **no fleet block**: candidate sizes and N0 come from the fleet posted.
3. ``python -m app run`` on it (memory store, the embedded worker sizing this city only, M = ``--days``).
   Before any history ``POST .../fleet/solve`` must answer 409 ``insufficient_history`` (0 of M days).
4. M operating days, the local days before the day of the hour a solve would size, each the horizon's
   epochs 200 s apart (72 a day) through ``POST .../epochs``: ``--taxis`` taxis (a quarter instrumented),
   each where the previous epoch left it (a matched taxi busy along the path the service gave it until the
   drop-off, a Step 3 taxi until its POI, a vacant one cruising a few blocks), about ``--riders`` new
   riders an epoch around two centres (riders not matched are posted again until the service expires them),
   and ``--tasks`` POI tasks registered for each day (before its epochs), the day sized for included.
5. ``POST .../fleet/solve``, then ``GET .../fleet/recommendation`` until the request's recommendation is
   published (the status's runs done logged on the way).

Measured: the import's wall time, the epochs (count, p50/p99/max of the round trip as the client sees it),
the time from the solve request to the recommendation, what the recommendation says (data window, n0,
sizes, the choices) and the service's peak resident memory (``bench.rss.TreePeak``: the process and its
tree, the worker's simulation processes included). Checked: source "recorded", n0 = the ordinary taxis
posted, sizes = ``spread_sizes`` of the instrumented taxis posted. Writes docs/perf_fleet_own_city.json and
the ``fleet-own-city`` section of docs/PERFORMANCE.md (``--no-write``: neither).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import httpx
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from app.usecases.fleet_history import spread_sizes
from bench.report import ROOT, stamp, write_section
from bench.rss import TreePeak
from services.city import Horizon
from tests.e2e.service import start_process, stop, wait_ready

CITY = "owncity"
TOKEN = "bench-own-city-admin-token"
TZ = "Asia/Shanghai"
HORIZON = Horizon(timezone=TZ)  # the import's defaults: 08:00-12:00 local, 4 intervals, epochs 200 s apart
BLOCK_M = 200.0
JSON_OUT = ROOT / "docs" / "perf_fleet_own_city.json"
SECTION = "fleet-own-city"

Log = Callable[[str], None]


# ---------------------------------------------------------------------------------------------- network


@dataclass
class Network:
    """The generated street grid: node ids by (col, row), the out-neighbours of each node (within the
    largest strongly connected part, where taxis and riders are placed), and what was generated."""

    side: int
    ids: np.ndarray
    usable: np.ndarray  # node ids of the largest strongly connected part
    out: dict[int, list[int]]
    info: dict[str, Any]

    def at(self, col: float, row: float, rng: np.random.Generator) -> int:
        """The node nearest grid position (col, row), or a random usable one when that node is cut off."""
        c = int(min(self.side - 1, max(0, round(col))))
        r = int(min(self.side - 1, max(0, round(row))))
        node = int(self.ids[r * self.side + c])
        return node if node in self.out else int(rng.choice(self.usable))


def write_network(directory: Path, side: int, seed: int) -> tuple[Path, Path, Network]:
    """nodes.csv and edges.csv of a jittered grid with one-way streets and missing links (module
    docstring)."""
    rng = np.random.default_rng(seed)
    n = side * side
    ids = 7_000_000 + rng.permutation(n * 3)[:n] * 7  # scattered external ids
    lat0, lon0 = 30.66, 104.06
    m_per_deg_lat, m_per_deg_lon = 111_320.0, 111_320.0 * math.cos(math.radians(lat0))
    x = (np.arange(n) % side) * BLOCK_M + rng.uniform(-30, 30, n)
    y = (np.arange(n) // side) * BLOCK_M + rng.uniform(-30, 30, n)
    lon, lat = lon0 + x / m_per_deg_lon, lat0 + y / m_per_deg_lat
    nodes = directory / "nodes.csv"
    nodes.write_text("id,lon,lat\n" + "".join(f"{ids[i]},{lon[i]:.7f},{lat[i]:.7f}\n" for i in range(n)))
    links: list[tuple[int, int]] = []
    one_way = missing = 0
    for r in range(side):
        for c in range(side):
            i = r * side + c
            for j, street, forward in ((i + 1, r, c + 1 < side), (i + side, c, r + 1 < side)):
                if not forward:
                    continue
                if street % 5 == 2:  # a one-way street, directions alternating street by street
                    links.append((i, j) if (street // 5) % 2 == 0 else (j, i))
                    one_way += 1
                    continue
                u = rng.random()
                if u < 0.02:  # both directions missing
                    missing += 2
                elif u < 0.04:  # one direction missing
                    links.append((i, j) if rng.random() < 0.5 else (j, i))
                    missing += 1
                else:
                    links += [(i, j), (j, i)]
    a = np.array([u for u, _ in links])
    b = np.array([v for _, v in links])
    length = np.hypot(x[a] - x[b], y[a] - y[b]) * rng.uniform(1.0, 1.15, len(links))
    edges = directory / "edges.csv"
    edges.write_text(
        "u,v,length_m\n"
        + "".join(f"{ids[u]},{ids[v]},{d:.1f}\n" for u, v, d in zip(a, b, length, strict=True))
    )
    adj = csr_matrix((np.ones(len(links)), (a, b)), shape=(n, n))
    _, labels = connected_components(adj, directed=True, connection="strong")
    keep = labels == np.bincount(labels).argmax()
    out: dict[int, list[int]] = {int(ids[i]): [] for i in np.flatnonzero(keep)}
    for u, v in links:
        if keep[u] and keep[v]:
            out[int(ids[u])].append(int(ids[v]))
    info = {
        "side": side,
        "nodes": n,
        "edges": len(links),
        "one_way_links": one_way,
        "missing_directions": missing,
        "largest_strongly_connected": int(keep.sum()),
        "block_m": BLOCK_M,
    }
    return nodes, edges, Network(side, ids, np.array(sorted(out)), out, info)


# ---------------------------------------------------------------------------------------------- platform


@dataclass
class Taxi:
    id: str
    instrumented: bool
    node: int
    path: list[int] = field(default_factory=list)  # the job's path (busy), external node ids
    start_s: float = 0.0
    end_s: float = 0.0  # when the job ends: vacant at the path's last node from then on

    def where(self, now: float) -> tuple[int, bool]:
        """The node the platform reports at ``now`` and whether the taxi is busy."""
        if self.path and now < self.end_s:
            frac = (now - self.start_s) / max(1.0, self.end_s - self.start_s)
            return self.path[min(len(self.path) - 1, int(frac * len(self.path)))], True
        if self.path:
            self.node, self.path = self.path[-1], []
        return self.node, False


@dataclass
class Rider:
    id: str
    origin: int
    destination: int
    requested_at: str
    posted: int = 0


class Platform:
    """A ride-hailing platform's view of its city: the fleet where it stands, riders waiting, and the
    epochs it posts (module docstring, step 4)."""

    def __init__(self, net: Network, taxis: int, riders: int, seed: int) -> None:
        self.net = net
        self.rng = np.random.default_rng(seed)
        self.riders_per_epoch = riders
        n1 = taxis // 4
        start = self.rng.choice(net.usable, size=taxis)
        self.taxis = [Taxi(f"{'i' if k < n1 else 'o'}{k:04d}", k < n1, int(start[k])) for k in range(taxis)]
        self.waiting: dict[str, Rider] = {}
        self.centres = ((0.3 * net.side, 0.35 * net.side), (0.7 * net.side, 0.65 * net.side))
        self.counter = 0

    def open_day(self, start_s: float) -> None:
        """The morning: yesterday's riders are gone, about a third of the fleet is on a trip."""
        self.waiting.clear()
        for t in self.taxis:
            t.path = []
            if self.rng.random() < 0.3:
                t.path = [t.node, self.net.at(*self._near(), self.rng)]
                t.start_s, t.end_s = start_s - 300.0, start_s + float(self.rng.uniform(60, 900))

    def _near(self) -> tuple[float, float]:
        cx, cy = self.centres[int(self.rng.integers(2))]
        sd = self.net.side / 8
        return float(self.rng.normal(cx, sd)), float(self.rng.normal(cy, sd))

    def _cruise(self, t: Taxi) -> None:
        for _ in range(int(self.rng.integers(0, 4))):
            t.node = int(self.rng.choice(self.net.out[t.node]))

    def epoch(self, epoch_id: str, when: dt.datetime) -> dict[str, Any]:
        now = when.timestamp()
        n_new = int(self.rng.poisson(self.riders_per_epoch))
        for _ in range(n_new):
            self.counter += 1
            origin = self.net.at(*self._near(), self.rng)
            if self.rng.random() < 0.5:
                dest = self.net.at(*self._near(), self.rng)
            else:
                dest = int(self.rng.choice(self.net.usable))
            asked = when - dt.timedelta(seconds=float(self.rng.uniform(0, HORIZON.epoch_s - 1)))
            rid = f"r{self.counter}"
            self.waiting[rid] = Rider(rid, origin, dest, asked.isoformat(timespec="seconds"))
        taxis = []
        for t in self.taxis:
            was_busy = bool(t.path)
            node, busy = t.where(now)
            if not busy and not was_busy:
                self._cruise(t)
                node = t.node
            taxis.append(
                {
                    "id": t.id,
                    "location": {"node": node},
                    "instrumented": t.instrumented,
                    "status": "busy" if busy else "vacant",
                }
            )
        riders = []
        for r in self.waiting.values():
            r.posted += 1
            riders.append(
                {
                    "id": r.id,
                    "origin": {"node": r.origin},
                    "destination": {"node": r.destination},
                    "requested_at": r.requested_at,
                }
            )
        return {"epoch_id": epoch_id, "time": when.isoformat(), "riders": riders, "taxis": taxis}

    def apply(self, when: dt.datetime, out: dict[str, Any]) -> dict[str, int]:
        """The service's decisions: matched taxis set off on their paths, matched and expired riders leave
        (and riders posted 6 times)."""
        now = when.timestamp()
        by_id = {t.id: t for t in self.taxis}
        for m in out["rider_matches"]:
            t = by_id[m["taxi_id"]]
            t.path, t.start_s = [int(v) for v in m["path"]] or [t.node], now
            t.end_s = now + float(m["wait_s"]) + float(m["trip_time_s"])
            self.waiting.pop(m["rider_id"], None)
        for a in out["task_assignments"]:
            t = by_id[a["taxi_id"]]
            t.path, t.start_s = [int(v) for v in a["path"]] or [t.node], now
            t.end_s = now + float(a["travel_time_s"])
        for rid in out["expired_rider_ids"]:
            self.waiting.pop(rid, None)
        for rid in [r.id for r in self.waiting.values() if r.posted >= 6]:
            del self.waiting[rid]
        return {"matches": len(out["rider_matches"]), "assignments": len(out["task_assignments"])}


# ---------------------------------------------------------------------------------------------- the run


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


def import_city(nodes: Path, edges: Path, cities: Path) -> float:
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "app", "import-city", CITY, "--nodes", str(nodes), "--edges", str(edges),
         "--timezone", TZ, "--source", "generated by bench/bench_fleet_own_city.py", "--out", str(cities)],
        cwd=ROOT, capture_output=True, text=True, timeout=1800,
    )  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"import-city failed ({done.returncode}): {done.stderr}")
    return time.monotonic() - started


def tasks_of(net: Network, day: dt.date, n: int, rng: np.random.Generator) -> list[dict[str, Any]]:
    """``n`` POI tasks of a local day, at nodes anywhere, scheduled through the horizon."""
    start = dt.datetime.combine(day, HORIZON.start, tzinfo=ZoneInfo(TZ))
    span = HORIZON.n_intervals * HORIZON.interval_s - 1200
    return [
        {
            "id": f"poi-{day.isoformat()}-{j:02d}",
            "location": {"node": int(rng.choice(net.usable))},
            "scheduled_at": (start + dt.timedelta(seconds=int(rng.uniform(0, span)))).isoformat(),
        }
        for j in range(n)
    ]


def wait_published(
    api: httpx.Client, base: str, request_id: str, timeout_s: float, log: Log
) -> dict[str, Any]:
    """The recommendation published for ``request_id``, logging the status's runs every 30 s."""
    deadline = time.monotonic() + timeout_s
    next_log = time.monotonic()
    while time.monotonic() < deadline:
        r = api.get(f"{base}/fleet/recommendation")
        if r.status_code == 200 and r.json()["request_id"] == request_id:
            return dict(r.json())
        entries = api.get(f"{base}/fleet/recommendations").json()["entries"]
        failed = [h for h in entries if h["request_id"] == request_id and h["status"] == "failed"]
        if failed:
            raise RuntimeError(f"the solve failed: {failed[0]['reason']}")
        if time.monotonic() >= next_log:
            solving = api.get(f"{base}/fleet/status").json().get("solving")
            log(f"  solving: {json.dumps(solving)[:300]}; load {os.getloadavg()[0]:.2f}")
            next_log += 30.0
        time.sleep(1.0)
    raise RuntimeError(f"no recommendation for {request_id} within {timeout_s:.0f} s")


def measure(args: argparse.Namespace, log: Log) -> dict[str, Any]:
    work = Path(tempfile.mkdtemp(prefix="bench-own-city-"))
    res: dict[str, Any] = {"loadavg_before": list(os.getloadavg())}
    try:
        nodes, edges, net = write_network(work, args.side, args.seed)
        res["network"] = net.info
        log(f"network: {json.dumps(net.info)}")
        res["import_s"] = import_city(nodes, edges, work / "cities")
        log(f"import-city: {res['import_s']:.1f} s")
        env = {
            "SD_STORE": "memory",
            "SD_CITIES_DIR": str(work / "cities"),
            "SD_WORKER_CITIES": json.dumps([CITY]),
            "SD_WORKER_DAYS": str(args.days),
            "SD_VAR_DIR": str(work / "var"),
        }
        (work / "var").mkdir()
        log_file = work / "service.log"
        proc, url = start_process(env, {TOKEN: ["read", "dispatch", "admin"]}, log_file=log_file)
        try:
            with TreePeak(proc.pid, interval_s=0.5) as peak:
                started = time.monotonic()
                wait_ready(url, proc, timeout_s=900.0)
                res["ready_s"] = time.monotonic() - started
                log(f"service ready in {res['ready_s']:.0f} s")
                with httpx.Client(
                    base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=600
                ) as api:
                    try:
                        drive(api, net, args, res, log)
                    except Exception:
                        tail = log_file.read_text(errors="replace").splitlines()[-40:]
                        log("service log, last lines:\n" + "\n".join(tail))
                        raise
            res["peak_rss_mb"] = {"process": peak.process_mb, "tree": peak.tree_rss_mb}
        finally:
            stop(proc)
            res["service_log_tail"] = log_file.read_text(errors="replace").splitlines()[-40:]
        res["loadavg_after"] = list(os.getloadavg())
    finally:
        if args.keep:
            log(f"kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    return res


def drive(api: httpx.Client, net: Network, args: argparse.Namespace, res: dict[str, Any], log: Log) -> None:
    """Steps 3-5 of the module docstring against the running service; fills ``res``."""
    base = f"/v1/cities/{CITY}"
    city = api.get(base).json()
    res["city_fleet_block"] = city["fleet"]
    res["imported_network"] = city["network"]
    log(f"city: network {city['network']}, fleet {city['fleet']}")
    target = HORIZON.coming_interval(time.time())
    solve_day = HORIZON.local_start(target).date()
    days = [solve_day - dt.timedelta(days=back) for back in range(args.days, 0, -1)]

    r = api.post(f"{base}/fleet/solve")
    res["before_history"] = {"status_code": r.status_code, "body": r.json()}
    log(f"solve before history: {r.status_code} {r.text[:300]}")
    if r.status_code != 409 or r.json().get("error") != "insufficient_history":
        raise RuntimeError(f"expected 409 insufficient_history, got {r.status_code} {r.text}")
    if r.json()["history"]["days"] != 0 or r.json()["history"]["needed"] != args.days:
        raise RuntimeError(f"unexpected history before posting: {r.text}")

    platform = Platform(net, args.taxis, args.riders, args.seed + 1)
    rng = np.random.default_rng(args.seed + 2)
    latencies: list[float] = []
    riders_posted = matches = assignments = 0
    per_epoch = HORIZON.n_intervals * HORIZON.interval_s // HORIZON.epoch_s
    posting = time.monotonic()
    for day in [*days, solve_day]:
        put = api.post(f"{base}/tasks", json=tasks_of(net, day, args.tasks, rng))
        if put.status_code != 200:
            raise RuntimeError(f"tasks of {day}: {put.status_code} {put.text}")
    new_per_day: list[int] = []
    for day in days:
        start = dt.datetime.combine(day, HORIZON.start, tzinfo=ZoneInfo(TZ))
        platform.open_day(start.timestamp())
        before = platform.counter
        day_lat: list[float] = []
        for e in range(per_epoch):
            when = start + dt.timedelta(seconds=HORIZON.epoch_s * e)
            body = platform.epoch(f"{day.isoformat()}-{e:03d}", when)
            riders_posted += len(body["riders"])
            t0 = time.perf_counter()
            r = api.post(f"{base}/epochs", json=body)
            day_lat.append(time.perf_counter() - t0)
            if r.status_code != 200:
                raise RuntimeError(f"epoch {body['epoch_id']}: {r.status_code} {r.text[:500]}")
            got = platform.apply(when, r.json())
            matches += got["matches"]
            assignments += got["assignments"]
        latencies += day_lat
        new_per_day.append(platform.counter - before)
        log(
            f"  {day}: {per_epoch} epochs, p50 {pct(day_lat, 50) * 1e3:.0f} ms, p99 {pct(day_lat, 99) * 1e3:.0f} "
            f"ms; load {os.getloadavg()[0]:.2f}"
        )
    res["epochs"] = {
        "n": len(latencies),
        "per_day": per_epoch,
        "wall_s": time.monotonic() - posting,
        "p50_ms": pct(latencies, 50) * 1e3,
        "p99_ms": pct(latencies, 99) * 1e3,
        "max_ms": max(latencies) * 1e3,
        "riders_posted": riders_posted,
        "new_riders": platform.counter,
        "new_riders_per_day": new_per_day,
        "rider_matches": matches,
        "task_assignments": assignments,
        "tasks_registered": args.tasks * (len(days) + 1),
    }
    st = api.get(f"{base}/fleet/status").json()
    if not st["history"]["enough"]:
        raise RuntimeError(f"history not enough after posting: {st['history']}")

    asked = time.monotonic()
    r = api.post(f"{base}/fleet/solve")
    if r.status_code != 202:
        raise RuntimeError(f"solve: {r.status_code} {r.text}")
    log(f"solve requested: {r.json()}")
    rec = wait_published(api, base, r.json()["request_id"], args.solve_timeout_s, log)
    res["solve_s"] = time.monotonic() - asked
    res["recommendation"] = summarize(rec)
    res["expected"] = {
        "days": [d.isoformat() for d in reversed(days)],
        "requests_per_day": list(reversed(new_per_day)),
        "n0": args.taxis - args.taxis // 4,
        "sizes": list(spread_sizes(args.taxis // 4)),
    }
    res["checks"] = checks(res["recommendation"], res["expected"])


def summarize(rec: dict[str, Any]) -> dict[str, Any]:
    sim, window = rec["simulation"], rec["data_window"]
    chosen = rec["chosen"]
    rh = rec.get("dro_rh_by_hour") or []
    return {
        "request_id": rec["request_id"],
        "interval": rec["interval"],
        "data_window": {k: window.get(k) for k in ("source", "days", "requests_per_day")},
        "simulation": {
            k: sim.get(k)
            for k in (
                "n0",
                "n0_source",
                "posted_ordinary",
                "posted_instrumented",
                "sizes_source",
                "fleet_start",
                "tasks_source",
                "n_tasks",
            )
        },
        "sizes": rec["sizes"],
        "chosen": chosen,
        "dro_rh_by_hour": [{k: h[k] for k in ("interval", "size", "observed_hours", "days")} for h in rh],
        "candidates": [
            {k: c[k] for k in ("size", "mean_cost_cny_per_h", "worst_case_cost_cny_per_h", "completion_mean")}
            for c in rec["candidates"]
        ],
        "subsidy_sweep": [
            {k: p[k] for k in ("subsidy_cny_per_vehicle_hour", "deterministic", "dro", "dro_rh")}
            for p in rec["subsidy_sweep"]
        ],
        "solve": rec["solve"],
        "subsidy_cny_per_vehicle_hour": rec["subsidy_cny_per_vehicle_hour"],
    }


def checks(rec: dict[str, Any], want: dict[str, Any]) -> dict[str, bool]:
    sim = rec["simulation"]
    return {
        "source_recorded": rec["data_window"]["source"] == "recorded",
        "days_are_the_posted_days": rec["data_window"]["days"] == want["days"],
        "requests_are_the_new_riders": rec["data_window"]["requests_per_day"] == want["requests_per_day"],
        "n0_is_ordinary_posted": sim["n0"] == want["n0"] and sim["n0_source"] == "recorded",
        "sizes_spread_instrumented_posted": rec["sizes"] == want["sizes"]
        and sim["sizes_source"] == "recorded",
        "fleet_start_recorded": sim["fleet_start"] == "recorded",
        "tasks_registered": sim["tasks_source"] == "registered",
    }


# ---------------------------------------------------------------------------------------------- report


def report(res: dict[str, Any]) -> str:
    net, ep, rec = res["network"], res["epochs"], res["recommendation"]
    imported = res["imported_network"]
    sim, window = rec["simulation"], rec["data_window"]
    chosen = rec["chosen"]

    reading = _reading(rec)
    rh = ", ".join(f"{h['interval'][-5:]} {h['size']}" for h in rec["dro_rh_by_hour"]) or "-"
    ok = all(res["checks"].values())
    rss = res.get("peak_rss_mb") or {}
    load = res["loadavg_before"], res["loadavg_after"]
    return "\n".join(
        [
            "## An imported city sized on the days and fleet it posted",
            "",
            res["stamp"],
            "",
            "What an operator bringing their own road network does, end to end through the API of one "
            "`python -m app run` (memory store, the embedded worker; `bench/bench_fleet_own_city.py`): a "
            f"generated {net['side']} x {net['side']} street grid ({net['nodes']:,} nodes, {net['edges']:,} "
            f"directed links: {net['one_way_links']:,} one-way, {net['missing_directions']} link directions "
            f"missing, positions jittered, ids scattered; once imported {imported['nodes']:,} nodes, "
            f"{imported['edges']:,} links, {imported['road_km']:,.0f} km of road) imported with `python -m "
            "app import-city` (no fleet block, the default horizon 08:00-12:00 Asia/Shanghai); the 409 "
            "`insufficient_history` checked before any epoch; then "
            f"{len(window['days'])} operating days of {ep['per_day']} epochs each posted through "
            f"`POST .../epochs`: {sim['posted_instrumented'] + sim['posted_ordinary']} taxis "
            f"({sim['posted_instrumented']} instrumented), each where the previous epoch left it (busy along "
            f"the service's path, vacant cruising), about {res['args']['riders']:g} new riders an epoch around "
            f"two centres, {res['args']['tasks']} tasks registered a day; then `POST .../fleet/solve` and the "
            f"recommendation polled. Load average before / after: "
            f"{', '.join(f'{v:.2f}' for v in load[0])} / {', '.join(f'{v:.2f}' for v in load[1])} (2 cores "
            "shared with other work).",
            "",
            "| measure | value |",
            "|---|---|",
            f"| import-city (CSV to bundle) | {res['import_s']:.1f} s |",
            f"| service ready (start-up, warm-up) | {res['ready_s']:.0f} s |",
            f"| epochs posted | {ep['n']} ({ep['riders_posted']:,} rider rows, {ep['new_riders']:,} new riders, "
            f"{ep['rider_matches']:,} matches, {ep['task_assignments']} Step 3 routes) in {ep['wall_s']:.0f} s |",
            f"| epoch round trip p50 / p99 / max | {ep['p50_ms']:.0f} / {ep['p99_ms']:.0f} / {ep['max_ms']:.0f} ms |",
            f"| solve request to recommendation published | {res['solve_s']:.0f} s |",
            f"| data_window.source, days, requests a day | {window['source']}, {len(window['days'])} "
            f"({window['days'][-1]} .. {window['days'][0]}), {window['requests_per_day']} |",
            f"| simulation.n0 (source) | {sim['n0']} ({sim['n0_source']}) |",
            f"| candidate sizes (source) | {rec['sizes']} ({sim['sizes_source']}) |",
            f"| chosen: deterministic / DRO / box LP / DRO_RH (hour solved for {rec['interval']}) | "
            f"{chosen['deterministic']} / {chosen['dro']} / {chosen['box_lp']} / {chosen['dro_rh']} |",
            f"| DRO_RH by hour | {rh} |",
            "| total cost per hour by size, mean / worst case in CNY/h (completion of the reachable tasks) | "
            + "; ".join(
                f"{c['size']}: {c['mean_cost_cny_per_h']:.1f} / {c['worst_case_cost_cny_per_h']:.1f}"
                + ("" if c["completion_mean"] is None else f" ({c['completion_mean']:.2f})")
                for c in rec["candidates"]
            )
            + " |",
            f"| DRO's choice against ζ (CNY per instrumented vehicle-hour; configured {rec['subsidy_cny_per_vehicle_hour']:g}) | "
            + ", ".join(f"{p['subsidy_cny_per_vehicle_hour']:g}: {p['dro']}" for p in rec["subsidy_sweep"])
            + " |",
            f"| the solve's runs (cached) / wall on the worker / jobs | {rec['solve']['runs']} "
            f"({rec['solve']['cached_runs']}) / {rec['solve']['wall_s']:.0f} s / {rec['solve']['jobs']} |",
            f"| fleet start, tasks | {sim['fleet_start']}, {sim['n_tasks']} {sim['tasks_source']} |",
            f"| peak RSS, service process / with its worker processes | {rss.get('process', 0):.0f} / "
            f"{rss.get('tree', 0):.0f} MB |",
            "",
            f"Checks ({'all pass' if ok else 'FAILED'}): "
            + ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in res["checks"].items())
            + ". Raw numbers: docs/perf_fleet_own_city.json.",
            *(["", reading] if reading else []),
        ]
    )


def _reading(rec: dict[str, Any]) -> str:
    """A sentence when DRO's choice is an end of the candidate range: the sizes beyond it were not simulated."""
    sizes, dro = rec["sizes"], rec["chosen"]["dro"]
    if dro not in (sizes[0], sizes[-1]):
        return ""
    end = "smallest" if dro == sizes[0] else "largest"
    c = {x["size"]: x for x in rec["candidates"]}
    step3 = {
        x: c[x]["mean_cost_cny_per_h"] - rec["subsidy_cny_per_vehicle_hour"] * x
        for x in (sizes[0], sizes[-1])
    }
    return (
        f"Reading: DRO picks the {end} candidate, {dro}; the recommendation does not say that the choice sits at "
        "an end of the range, and no size beyond it was simulated (`fleet.sizes` in the city's `city.json` "
        f"sets others). Between {sizes[0]} and {sizes[-1]} instrumented taxis the mean Step 3 cost goes from "
        f"{step3[sizes[0]]:.1f} to {step3[sizes[-1]]:.1f} CNY/h while the subsidy "
        f"(ζ = {rec['subsidy_cny_per_vehicle_hour']:g}) adds "
        f"{rec['subsidy_cny_per_vehicle_hour'] * (sizes[-1] - sizes[0]):.0f} CNY/h."
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--side", type=int, default=60, help="streets each way of the grid")
    ap.add_argument("--taxis", type=int, default=600, help="taxis posted, a quarter of them instrumented")
    ap.add_argument("--days", type=int, default=10, help="M: operating days posted, the worker's M")
    ap.add_argument("--riders", type=float, default=25.0, help="new riders an epoch (mean)")
    ap.add_argument("--tasks", type=int, default=40, help="POI tasks registered a day")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--solve-timeout-s", type=float, default=3600.0)
    ap.add_argument("--keep", action="store_true", help="keep the work directory (CSV, bundle, service log)")
    ap.add_argument("--json-out", type=Path, default=JSON_OUT)
    ap.add_argument("--no-write", action="store_true", help="print the section, write nothing")
    ap.add_argument("--report-only", type=Path, default=None, help="write the section from this JSON")
    args = ap.parse_args()
    if args.report_only is not None:
        print(write_section(SECTION, report(json.loads(args.report_only.read_text()))))
        return 0
    if args.taxis < 4 or args.days < 2 or args.side < 4:
        ap.error("at least 4 taxis, 2 days and a 4 x 4 grid")

    def log(m: str) -> None:
        print(m, flush=True)

    res = measure(args, log)
    res["args"] = {k: v for k, v in vars(args).items() if k not in ("json_out", "report_only")}
    res["stamp"] = stamp(" ".join(["python -m bench.bench_fleet_own_city", *sys.argv[1:]]))
    log(json.dumps({k: v for k, v in res.items() if k != "service_log_tail"}, indent=1, default=str))
    if not args.no_write:
        args.json_out.write_text(json.dumps(res, indent=2, default=str) + "\n")
    text = report(res)
    if args.no_write:
        print(text)
    else:
        print(write_section(SECTION, text))
    return 0 if all(res["checks"].values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
