"""Epoch latency: the dispatch core in-process, the service over HTTP, and the floor beside them.

Scenarios are data (``SCENARIOS``); every run is seeded. The floor is the unavoidable work of an epoch,
measured on the same inputs in the same run: one full shortest-path tree per vacant taxi (scipy, all
sources in one call) plus one assignment over taxis x riders.

    python -m bench.bench_epoch                 # both scales, in-process and HTTP, writes docs/PERFORMANCE.md
    python -m bench.bench_epoch --epochs 20 --no-http --no-write   # a quick look
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
import scipy.sparse.csgraph as cg
from scipy.optimize import linear_sum_assignment

from bench.report import stamp, write_section
from services import routing
from services.city import City
from services.citydata import load_city
from services.dispatch import decide
from services.model import CountsView, IntervalKey, Rider, RiderId, Snapshot, Task, TaskId, Taxi, TaxiId

ROOT = Path(__file__).resolve().parents[1]
BUNDLES = ROOT / "app" / "data" / "cities"


@dataclass(frozen=True)
class Scenario:
    name: str
    city: str
    n_instrumented: int
    n_ordinary: int
    riders_mean: float
    max_open_tasks: int
    epochs: int
    seed: int = 20261122


SCENARIOS = {
    "paper": Scenario("paper", "chengdu", 60, 60, 10.0, 85, 200),
    "city": Scenario("city", "manhattan", 600, 1400, 400.0, 300, 200),
}


def epochs(city: City, sc: Scenario, n: int) -> Iterator[tuple[Snapshot, list[Task]]]:
    """Seeded epochs 200 s apart from 08:00 local: taxis at random nodes, Poisson riders, a random number
    (0..max) of open tasks at random nodes."""
    rng = np.random.default_rng(sc.seed)
    tz = ZoneInfo(city.horizon.timezone)
    t0 = dt.datetime(2026, 11, 23, 8, 0, tzinfo=tz).timestamp()
    nn = city.network.n_nodes
    for e in range(n):
        now = t0 + e * city.horizon.epoch_s
        nr = int(rng.poisson(sc.riders_mean))
        riders = tuple(
            Rider(
                RiderId(f"r{e}-{i}"),
                int(rng.integers(nn)),
                int(rng.integers(nn)),
                now - float(rng.uniform(0, 300)),
            )
            for i in range(nr)
        )
        taxis = tuple(
            Taxi(TaxiId(f"i{i}"), int(rng.integers(nn)), True, True) for i in range(sc.n_instrumented)
        ) + tuple(Taxi(TaxiId(f"o{i}"), int(rng.integers(nn)), False, True) for i in range(sc.n_ordinary))
        nt = int(rng.integers(0, sc.max_open_tasks + 1))
        tasks = [Task(TaskId(f"k{e}-{i}"), int(rng.integers(nn)), now - 60.0) for i in range(nt)]
        yield Snapshot(f"e{e}", now, riders, taxis), tasks


def floor_once(city: City, snap: Snapshot) -> float:
    """One full tree per vacant taxi plus one assignment (taxis x riders), timed."""
    graph = city.network.csr(city.network.edge_time_s)
    sources = np.array([t.node for t in snap.taxis if t.vacant])
    t = time.perf_counter()
    dist = cg.dijkstra(graph, indices=sources)
    cols = np.array([r.origin for r in snap.riders], dtype=np.int64)
    if len(cols):
        linear_sum_assignment(dist[:, cols])
    return time.perf_counter() - t


def run_inprocess(sc: Scenario, n: int) -> dict[str, list[float]]:
    """Each epoch solved twice, with the default ``routing.WORKERS`` threads and with one (in alternating
    order, so neither always runs first), the two decisions checked equal, then the floor."""
    city = load_city(BUNDLES / sc.city)
    counts: dict[IntervalKey, np.ndarray] = {}
    visited: dict[TaxiId, set[tuple[IntervalKey, int]]] = {}
    lat, lat1, flo, horizon = [], [], [], []
    warm = next(epochs(city, sc, 1))
    decide(city, CountsView({}), *warm)  # compile and cache outside the timing
    workers = routing.WORKERS
    for e, (snap, tasks) in enumerate(epochs(city, sc, n)):
        view = CountsView(dict(counts), {k: frozenset(v) for k, v in visited.items()})
        out: dict[int, tuple[float, object]] = {}
        for w in (workers, 1) if e % 2 == 0 else (1, workers):
            routing.WORKERS = w
            try:
                t = time.perf_counter()
                d = decide(city, view, snap, tasks)
                out[w] = (time.perf_counter() - t, d)
            finally:
                routing.WORKERS = workers
        if out[workers][1] != out[1][1]:
            raise AssertionError(f"epoch {e}: the decision depends on the number of threads")
        lat.append(out[workers][0])
        lat1.append(out[1][0])
        d = out[workers][1]  # type: ignore[assignment]
        horizon.append(float(city.horizon.in_horizon(city.horizon.interval_of(snap.time_s))))
        for v in d.visits:  # commit, so counts evolve as they would in service
            if (v.interval, v.cell) not in visited.setdefault(v.taxi_id, set()):
                visited[v.taxi_id].add((v.interval, v.cell))
                counts.setdefault(v.interval, np.zeros(city.grid.n_cells, dtype=np.int64))[v.cell] += 1
        flo.append(floor_once(city, snap))
    return {"latency": lat, "latency_1thread": lat1, "floor": flo, "in_horizon": horizon}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_http(sc: Scenario, n: int) -> dict[str, list[float]]:
    """Start the real service (uvicorn, in-memory store) and post the same epochs over HTTP."""
    import httpx

    city = load_city(BUNDLES / sc.city)
    port = _free_port()
    token = "bench-token"
    env = {**os.environ, "SD_PORT": str(port), "SD_TOKENS": json.dumps({token: ["read", "dispatch"]})}
    proc = subprocess.Popen(
        [sys.executable, "-m", "app", "run"],
        env=env,
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    ids = city.network.node_ids
    lat: list[float] = []
    try:
        with httpx.Client(
            base_url=f"http://127.0.0.1:{port}", timeout=60.0, headers={"Authorization": f"Bearer {token}"}
        ) as client:
            for _ in range(300):
                try:
                    if client.get("/readyz").status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                time.sleep(0.1)
            else:
                raise RuntimeError("the service did not become ready")
            for e, (snap, tasks) in enumerate(epochs(city, sc, n + 1)):
                if tasks:
                    client.post(
                        f"/v1/cities/{sc.city}/tasks",
                        json=[
                            {
                                "id": t.id,
                                "location": {"node": int(ids[t.node])},
                                "scheduled_at": _iso(city, t.scheduled_at_s),
                            }
                            for t in tasks
                        ],
                    ).raise_for_status()
                body = {
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
                t = time.perf_counter()
                r = client.post(f"/v1/cities/{sc.city}/epochs", json=body)
                dt_s = time.perf_counter() - t
                r.raise_for_status()
                if e > 0:  # the first epoch compiles the kernels in the server process
                    lat.append(dt_s)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    return {"latency": lat}


def _iso(city: City, t: float) -> str:
    return dt.datetime.fromtimestamp(t, tz=ZoneInfo(city.horizon.timezone)).isoformat()


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
    ap.add_argument("--epochs", type=int, default=None, help="override the scenario's epoch count")
    ap.add_argument("--no-http", action="store_true")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--report-only", type=Path, metavar="JSON", help="rewrite the report from saved results")
    args = ap.parse_args(argv)
    if args.report_only:
        write_report(json.loads(args.report_only.read_text()))
        return 0
    results = {}
    for name in args.scenario or ["paper", "city"]:
        sc = SCENARIOS[name]
        n = args.epochs or sc.epochs
        print(f"[{name}] in-process, {n} epochs ...", flush=True)
        load_before = os.getloadavg()
        r = run_inprocess(sc, n)
        inside = [x for x, h in zip(r["latency"], r["in_horizon"], strict=True) if h]
        res = {
            "scenario": sc.__dict__,
            "workers": routing.WORKERS,
            "inprocess": summary(r["latency"]),
            "inprocess_1thread": summary(r["latency_1thread"]),
            "floor": summary(r["floor"]),
        }
        if inside:
            res["inprocess_in_horizon"] = summary(inside)
        if not args.no_http:
            print(f"[{name}] over HTTP, {n} epochs ...", flush=True)
            res["http"] = summary(run_http(sc, n)["latency"])
        res["load_average"] = {"before": list(load_before), "after": list(os.getloadavg())}
        results[name] = res
        print(json.dumps(res, indent=1), flush=True)
        (ROOT / "bench" / "out").mkdir(exist_ok=True)
        (ROOT / "bench" / "out" / "last_epoch_results.json").write_text(json.dumps(results, indent=1))
    if not args.no_write:
        write_report(results)
    return 0


def write_report(results: dict[str, dict]) -> None:
    lines = [
        "## Epoch latency",
        "",
        stamp("python -m bench.bench_epoch"),
        "",
        "Inputs (seeded, `bench/bench_epoch.py` `SCENARIOS`): taxis at random nodes, Poisson riders requested",
        "0-300 s earlier, a uniformly random number of open tasks (0..max) at random nodes, epochs 200 s apart from",
        "08:00 local; counts evolve as the decisions are committed. In-process = `services.dispatch.decide` alone,",
        "with its default threads (`services.routing.WORKERS`, the CPUs it may use, at most 4) and, on the same",
        "epochs in alternating order, with one thread (`inprocess-1thread`; the two decisions are checked equal);",
        "HTTP = a real `python -m app run` (uvicorn, in-memory store) with the client's round trip; floor = one",
        "full shortest-path tree per vacant taxi (scipy, one call, one thread) plus one assignment, on the same",
        "epochs.",
        "",
        "| scale | city | taxis (instr.) | riders/epoch | open tasks | epochs | path | p50 ms | p99 ms | min-max ms | IQR ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    labels = {
        "inprocess": "inprocess",
        "inprocess_1thread": "inprocess-1thread",
        "http": "http",
        "floor": "floor",
    }
    for name, r in results.items():
        sc = r["scenario"]
        for how, label in labels.items():
            if how not in r:
                continue
            s = r[how]
            if how == "inprocess" and "workers" in r:
                label = f"inprocess ({r['workers']} threads)"
            lines.append(
                f"| {name} | {sc['city']} | {sc['n_instrumented'] + sc['n_ordinary']} ({sc['n_instrumented']}) | "
                f"~{sc['riders_mean']:.0f} | 0..{sc['max_open_tasks']} | {s['n']} | {label} | {s['p50_ms']:.1f} | "
                f"{s['p99_ms']:.1f} | {s['min_ms']:.1f}-{s['max_ms']:.1f} | {s['iqr_ms']:.1f} |"
            )
    lines += [
        "",
        "Targets (issue 2): paper scale p99 <= 3x the floor and <= 100 ms in-process; city scale p99 <= 1 s.",
        "",
    ]
    limits = {"paper": (3.0, 100.0), "city": (None, 1000.0)}
    for name, r in results.items():
        for how in ("inprocess", "inprocess_1thread"):
            if how not in r:
                continue
            p99 = r[how]["p99_ms"]
            ratio = p99 / r["floor"]["p99_ms"]
            max_ratio, max_ms = limits.get(name, (None, None))
            verdicts = []
            if max_ratio is not None:
                verdicts.append(f"ratio target {'met' if ratio <= max_ratio else 'NOT met'}")
            if max_ms is not None:
                verdicts.append(f"{max_ms:.0f} ms target {'met' if p99 <= max_ms else 'NOT met'}")
            threads = "1 thread" if how == "inprocess_1thread" else f"{r.get('workers', '?')} threads"
            lines.append(
                f"- {name}, {threads}: in-process p99 {p99:.0f} ms, {ratio:.2f}x the floor's p99 "
                f"({'; '.join(verdicts)})"
            )
    for name, r in results.items():
        if "load_average" in r:
            before, after = r["load_average"]["before"], r["load_average"]["after"]
            lines.append(
                f"- {name}: load average (1/5/15 min) {before[0]:.2f}/{before[1]:.2f}/{before[2]:.2f} before, "
                f"{after[0]:.2f}/{after[1]:.2f}/{after[2]:.2f} after its runs (the machine is shared)"
            )
    inside = ", ".join(
        f"{name} {r['inprocess_in_horizon']['n']} of {r['inprocess']['n']}"
        for name, r in results.items()
        if "inprocess_in_horizon" in r
    )
    lines += [
        "",
        f"Where the time goes: the tail is the epochs inside the sensing horizon (08:00-12:00: {inside or '-'};",
        "`inprocess_in_horizon` in the JSON) with many open tasks; outside it every gain is 0 and Step 3 grows",
        "only the fastest-path tree. Step 3 grows four trees per vacant instrumented taxi (one per kappa), each until",
        "every open POI is settled, on the network with degree-2 chains contracted (`services/contraction.py`;",
        "Chengdu 6,536 -> 2,236 nodes, Manhattan barely contracts), and evaluates every POI's route in one walk over",
        "the tree; Algorithm 2 re-plans each matched taxi with three more trees (its fastest path is Step 3's).",
        "Independent searches (Step 3's taxis, the riders' pickup and service searches, batches of Algorithm 2",
        "re-plans) share the threads; on this 2-vCPU machine two threads give about 1.3-1.4x on the searches. The",
        "raw numbers of the last run are in `docs/perf_epoch.json`.",
    ]
    path = write_section("epoch", "\n".join(lines))
    (ROOT / "docs" / "perf_epoch.json").write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
