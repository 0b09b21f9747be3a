"""The whole service on one command: epoch latency while the embedded fleet worker solves against without,
interleaved in one run, at the paper's scale (Chengdu) and at a platform's (metro250k); the time from a solve
request to the recommendation.

    python -m bench.bench_fleet_service                      # both scales, write docs/PERFORMANCE.md, screenshot
    python -m bench.bench_fleet_service --scale chengdu --rounds 2 --no-write   # a quick look
    python -m bench.bench_fleet_service --report-only docs/perf_fleet_service/*.json   # one JSON per scale

Each scale starts the service as `make run` starts it (`python -m app run`: memory store, the fleet worker
inside it with its defaults: local simulation processes at niceness +10, paused while an epoch is solved),
with a token, a free port, a fresh `SD_VAR_DIR` and the worker sizing only the measured city. A client posts
epochs over HTTP back to back for the whole run (an epoch's latency is its round trip as the client sees it:
the body built, the decision read), while a controller alternates phases: no solve for `--quiet-s` seconds,
then a solve, `--rounds` times, then a last no-solve phase. An epoch belongs to a phase when it started and
ended inside it; the drift of the load over the run (open tasks pile up) falls on both samples alike.

* **chengdu** (the paper's scale): the replay client's days (`python -m app replay` defaults: scenario 1,
  60 + 60 taxis, 85 POI tasks, 72 epochs a day), day after day. A solve phase is one whole solve asked by
  `POST .../fleet/solve` with the run cache emptied first (all 60 runs simulated: 6 sizes x M = 10 synthetic
  days), from the first status showing it running to the status showing it published (the plan, DRO and
  sweep on the worker's thread included). The dashboard with the last recommendation is then saved as
  docs/figures/dashboard.png (the README shows it) in Debian's chromium.
* **metro250k** (a platform's scale): the generated metropolitan city (`bench/metro.py`) imported with a
  POI file around its centres (its synthetic history's demand generator: `fleet.synthetic_history`) and the
  platform's fleet as its sizing configuration (`fleet.sizes` a quarter to twice 1,500 instrumented taxis,
  `fleet.n0` 3,500, M = 10 days, 6,000 requests an hour, 400 tasks); the epochs are the epoch benchmark's
  `metro250k` platform load (`bench.load.Platform`: 1,500 + 3,500 taxis, 800 riders, 100 new tasks an epoch).
  A re-solve there takes an hour, so a solve phase is `--metro-solve-s` seconds of a requested solve's runs
  in progress (from the status showing a run started), after which the benchmark ends that solve by killing
  the worker's simulation processes (the solve is reported failed; the next request starts a fresh pool).

Per phase the worker processes' CPU seconds are read from /proc: how far the runs got while the epochs ran.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime as dt
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import httpx
import numpy as np
import psutil

from app.adapters.city_registry import CityRegistry
from app.entrypoints.replay_client import HttpDispatcher
from app.runs import RunSpec, demand_for, open_bundle, tasks_for
from app.usecases.fleet_history import spread_sizes
from bench import metro
from bench.report import ROOT, stamp, write_section
from services.city import City
from services.citydata import CityMeta, save_bundle
from services.sim.demand import demand_on_date
from services.sim.engine import SimConfig, simulate
from tests.e2e.service import start_process, stop, wait_ready

CITY = "chengdu"
METRO = "metro250k"
TOKEN = "bench-fleet-admin-token"
JSON_OUT = ROOT / "docs" / "perf_fleet_service" / "last.json"
SCREENSHOT = ROOT / "docs" / "figures" / "dashboard.png"
FIRST_DATE = dt.date(2025, 1, 1)  # far before the clock: outside the look-back of recorded history
TARGET_RATIO = 1.3
METRO_FLEET = (1500, 3500)  # instrumented, ordinary: the epoch benchmark's metro250k load
METRO_RATE_PER_HOUR = 6000.0
METRO_TASKS = 400
METRO_POIS = 3000
POLL_S = 0.25

Log = Callable[[str], None]
Kind = Literal["quiet", "solve"]


@dataclass
class Recorder:
    """Each epoch's (start, end) on the monotonic clock, appended by the client."""

    epochs: list[tuple[float, float]] = field(default_factory=list)

    def add(self, start: float, end: float) -> None:
        self.epochs.append((start, end))


@dataclass(frozen=True)
class Phase:
    """A window of the run: no solve, or a solve in progress (its worker CPU seconds, what it reached)."""

    kind: Kind
    start: float
    end: float
    worker_cpu_s: float = 0.0
    note: dict[str, Any] = field(default_factory=dict)


@dataclass
class Service:
    proc: Any
    api: httpx.Client
    city: str
    var: Path


@contextmanager
def service(city: str, env: dict[str, str], log: Log) -> Iterator[Service]:
    """``python -m app run`` with the worker sizing ``city`` only, a fresh var dir; stopped on the way out."""
    var = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    full = {"SD_STORE": "memory", "SD_VAR_DIR": str(var), "SD_WORKER_CITIES": json.dumps([city]), **env}
    proc, url = start_process(full, {TOKEN: ["read", "dispatch", "admin"]}, log_file=var / "service.log")
    try:
        started = time.monotonic()
        wait_ready(url, proc, timeout_s=900.0)
        log(f"{city}: service ready in {time.monotonic() - started:.0f} s")
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=600) as api:
            st = api.get(f"/v1/cities/{city}/fleet/status").json()
            assert st["worker"]["seen"] and st["worker"]["workers"][0]["embedded"], st
            yield Service(proc, api, city, var)
    finally:
        stop(proc)
        shutil.rmtree(var, ignore_errors=True)


def status(svc: Service) -> dict[str, Any]:
    return dict(svc.api.get(f"/v1/cities/{svc.city}/fleet/status").json())


def worker_processes(svc: Service) -> list[psutil.Process]:
    """The worker's simulation processes: the service's grandchildren (the pool's processes, forked by
    its forkserver)."""
    out: list[psutil.Process] = []
    for child in psutil.Process(svc.proc.pid).children():
        try:
            out.extend(child.children())
        except psutil.NoSuchProcess:
            continue
    return out


def worker_cpu_s(svc: Service) -> float:
    total = 0.0
    for p in worker_processes(svc):
        try:
            t = p.cpu_times()
        except psutil.NoSuchProcess:
            continue
        total += t.user + t.system
    return total


def wait_idle(svc: Service) -> float:
    """Wait until the status shows no solve running or pending; when."""
    while True:
        st = status(svc)
        if st["solving"] is None and st["pending_request"] is None:
            return time.monotonic()
        time.sleep(POLL_S)


def quiet_phase(svc: Service, seconds: float, phases: list[Phase], stop_at: threading.Event) -> None:
    start = wait_idle(svc) + 1.0
    stop_at.wait(max(0.0, start + seconds - time.monotonic()))
    phases.append(Phase("quiet", start, time.monotonic()))


def request_solve(svc: Service) -> str:
    r = svc.api.post(f"/v1/cities/{svc.city}/fleet/solve")
    assert r.status_code == 202, r.text
    return str(r.json()["request_id"])


def running(svc: Service, request_id: str, runs_started: bool) -> dict[str, Any]:
    """Wait until the status shows the request's solve running (with a run started, if asked); the status."""
    while True:
        st = status(svc)
        s = st["solving"]
        if s is not None and s["request_id"] == request_id and (not runs_started or s["runs_running"] > 0):
            return st
        time.sleep(POLL_S)


def ended(svc: Service, request_id: str) -> dict[str, Any]:
    """Wait until the request's solve is the last solve (published or failed); its entry."""
    while True:
        last = status(svc)["last_solve"]
        if last is not None and last.get("request_id") == request_id:
            return dict(last)
        time.sleep(POLL_S)


def chengdu_solve_phase(svc: Service, phases: list[Phase], solves: list[dict[str, Any]]) -> None:
    """One whole solve from an empty run cache: from the status showing it running to it published."""
    shutil.rmtree(svc.var / "fleet-runs", ignore_errors=True)
    asked = time.monotonic()
    request_id = request_solve(svc)
    running(svc, request_id, runs_started=False)
    start, cpu0 = time.monotonic(), worker_cpu_s(svc)
    cpu_last = cpu0
    done: dict[str, Any] | None = None
    while done is None:
        cpu_last = max(cpu_last, worker_cpu_s(svc))  # the pool's processes stay: read before the end
        last = status(svc)["last_solve"]
        if last is not None and last.get("request_id") == request_id:
            done = dict(last)
        else:
            time.sleep(POLL_S)
    end = time.monotonic()
    assert done["status"] == "published", done
    solve = svc.api.get(f"/v1/cities/{svc.city}/fleet/recommendation").json()["solve"]
    solves.append({"request_to_published_s": end - asked, "runs": solve["runs"], "wall_s": solve["wall_s"]})
    phases.append(Phase("solve", start, end, cpu_last - cpu0, {"status": done["status"]}))


def bounded_solve_phase(svc: Service, seconds: float, phases: list[Phase], log: Log) -> None:
    """A requested solve's runs in progress for ``seconds``, then ended by killing the worker's processes
    (the run cache emptied first: every run is simulated)."""
    shutil.rmtree(svc.var / "fleet-runs", ignore_errors=True)
    request_id = request_solve(svc)
    running(svc, request_id, runs_started=True)
    start, cpu0 = time.monotonic(), 0.0  # the pool's processes are new: their CPU so far is the solve's
    time.sleep(seconds)
    st = status(svc)["solving"]
    cpu = worker_cpu_s(svc) - cpu0
    procs = worker_processes(svc)
    end = time.monotonic()
    for p in procs:
        try:
            p.kill()
        except psutil.NoSuchProcess:
            continue
    last = ended(svc, request_id)
    note = {"runs_done": st["runs_done"], "runs_running": st["runs_running"], "runs_total": st["runs_total"]}
    log(
        f"{svc.city} solve phase: {note}, worker CPU {cpu:.0f} s in {end - start:.0f} s; ended {last['status']}"
    )
    phases.append(Phase("solve", start, end, cpu, note))


def percentiles(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64) * 1000.0
    if a.size == 0:
        return {"n": 0, "p50_ms": float("nan"), "p99_ms": float("nan"), "max_ms": float("nan")}
    return {
        "n": int(a.size),
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "mean_ms": float(a.mean()),
    }


def in_phase(epochs: list[tuple[float, float]], ph: Phase) -> list[float]:
    return [e - s for s, e in epochs if ph.start <= s and e <= ph.end]


def summarize(rec: Recorder, phases: list[Phase]) -> dict[str, Any]:
    """Per kind: the epochs of all its phases pooled; per phase: its own; the p99 ratio solve / quiet."""
    epochs = list(rec.epochs)
    pooled: dict[str, list[float]] = {"quiet": [], "solve": []}
    rows = []
    for ph in phases:
        lat = in_phase(epochs, ph)
        pooled[ph.kind].extend(lat)
        rows.append({**dataclasses.asdict(ph), "duration_s": ph.end - ph.start, **percentiles(lat)})
    quiet, solve = percentiles(pooled["quiet"]), percentiles(pooled["solve"])
    return {
        "without_solve": quiet,
        "during_solve": solve,
        "p99_ratio": solve["p99_ms"] / quiet["p99_ms"],
        "p50_ratio": solve["p50_ms"] / quiet["p50_ms"],
        "phases": rows,
    }


def alternate(
    quiet: Callable[[], None], solve: Callable[[], None], rounds: int, done: threading.Event
) -> threading.Thread:
    """A thread running quiet, solve, quiet, solve ..., quiet (``rounds`` solves), then setting ``done``."""

    def run() -> None:
        try:
            for _ in range(rounds):
                quiet()
                solve()
            quiet()
        finally:
            done.set()

    t = threading.Thread(target=run, name="phases", daemon=True)
    t.start()
    return t


# ---------------------------------------------------------------------------------------------- chengdu


class TimedDispatcher(HttpDispatcher):
    """The replay client, recording when each epoch's POST started and ended."""

    def __init__(self, client: httpx.Client, rec: Recorder) -> None:
        bundle = open_bundle(CityRegistry().bundle_dir(CITY))
        super().__init__(client, CITY, bundle.city)
        self.rec = rec

    def _request(self, method: str, url: str, what: str, **kwargs: Any) -> httpx.Response:
        started = time.monotonic()
        r = super()._request(method, url, what, **kwargs)
        if method == "POST" and url.endswith("/epochs"):
            self.rec.add(started, time.monotonic())
        return r


def replay_day(client: httpx.Client, rec: Recorder, day: int) -> None:
    """One day of the replay defaults on date FIRST_DATE + day (demand day ``day`` of the generator)."""
    spec = RunSpec(CITY, 1, 60, 60, 0, day, True, False, 85)
    bundle = open_bundle(CityRegistry().bundle_dir(CITY))
    date = (FIRST_DATE + dt.timedelta(days=day)).isoformat()
    demand = demand_on_date(demand_for(spec, bundle), bundle.city.horizon, date)
    prefix = f"bench{day}-"
    tasks = tasks_for(spec, bundle, demand.date, prefix)
    config = SimConfig(n_instrumented=60, n_ordinary=60, n_tasks=85, seed=0, id_prefix=prefix)
    simulate(bundle.city, demand, tasks, config, TimedDispatcher(client, rec))


def measure_chengdu(
    rounds: int, quiet_s: float, solve_s: float | None, shot: bool, log: Log
) -> dict[str, Any]:
    """Whole solves (``solve_s`` None), else solve phases of ``solve_s`` seconds of runs in progress."""
    rec, phases, solves = Recorder(), [], []  # type: ignore[var-annotated]
    with service(CITY, {}, log) as svc:
        replay_day(svc.api, Recorder(), 0)  # the first day loads the city's state: untimed
        load_before = os.getloadavg()
        done = threading.Event()
        ctl = alternate(
            lambda: quiet_phase(svc, quiet_s, phases, done),
            lambda: (
                chengdu_solve_phase(svc, phases, solves)
                if solve_s is None
                else bounded_solve_phase(svc, solve_s, phases, log)
            ),
            rounds,
            done,
        )
        day = 1
        while not done.is_set():
            replay_day(svc.api, rec, day)
            day += 1
            if day % 10 == 0:
                log(f"chengdu: {day} days, {len(rec.epochs)} epochs, {len(phases)} phases")
        ctl.join()
        load_after = os.getloadavg()
        if shot:
            screenshot(str(svc.api.base_url))
    return {
        **summarize(rec, phases),
        "solves": solves,
        "days_replayed": day,
        "loadavg_before": list(load_before),
        "loadavg_after": list(load_after),
        "rounds": rounds,
        "quiet_s": quiet_s,
        "solve_s": solve_s,
    }


def screenshot(url: str) -> None:
    """The dashboard with the recommendation, in Debian's chromium."""
    from playwright.sync_api import sync_playwright

    from tests.e2e.browser import CHROMIUM, CHROMIUM_ARGS

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        page = browser.new_page(viewport={"width": 1400, "height": 1300})
        page.goto(f"{url}/dashboard?poll=5")
        page.fill("#token", TOKEN)
        page.click("#connect")
        page.locator("#fleet-body").wait_for(state="visible", timeout=60_000)
        page.wait_for_timeout(1500)
        SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SCREENSHOT), full_page=True)
        browser.close()


# ---------------------------------------------------------------------------------------------- metro250k


def metro_bundle(city: City, directory: Path) -> Path:
    """metro250k as a platform imports it, with POIs around its centres (the synthetic history's demand
    generator) and the platform's fleet as its sizing configuration."""
    from bench.load import Centres

    xy, weight = metro.centre_layout(city)
    nodes = Centres(city, xy, weight, 2_500.0)(np.random.default_rng(20261127), METRO_POIS)
    n1, n0 = METRO_FLEET
    meta = CityMeta(
        name=METRO,
        timezone=city.horizon.timezone,
        source="generated",
        files={"pois": "pois.csv"},
        fleet={"synthetic_history": True, "sizes": list(spread_sizes(n1)), "n0": n0},
    )
    out = save_bundle(directory / METRO, city.network, meta)
    with (out / "pois.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["lon", "lat"])
        for v in nodes.tolist():
            w.writerow([f"{city.network.lon[v]:.7f}", f"{city.network.lat[v]:.7f}"])
    return out


class MetroLoad:
    """The epoch benchmark's metro250k platform load over HTTP, one epoch at a time, recorded."""

    def __init__(self, svc: Service, city: City, rec: Recorder) -> None:
        from bench.bench_epoch import SCENARIOS, Epochs, _Service

        self.city = city
        self.rec = rec
        self.epochs = Epochs(SCENARIOS[METRO], city)
        self.target = _Service(svc.proc, svc.api, METRO, 0.0)
        self.posted = 0

    def post(self, record: bool = True) -> None:
        from app.usecases.epoch_record import decision_of
        from bench.bench_epoch import _post_epoch
        from services.model import RiderId

        snap, tasks = self.epochs.next()
        took, doc = _post_epoch(self.target, self.city, snap, tasks)
        end = time.monotonic()
        if record:
            self.rec.add(end - took, end)
        d = decision_of(self.city, doc)
        assert self.epochs.platform is not None
        expired = tuple(RiderId(x) for x in doc["expired_rider_ids"])
        self.epochs.platform.apply(d.rider_matches, d.task_assignments, expired)
        self.posted += 1


def measure_metro(rounds: int, quiet_s: float, solve_s: float, gap_s: float, log: Log) -> dict[str, Any]:
    started = time.monotonic()
    city = metro.metro_city()
    log(f"metro250k built in {time.monotonic() - started:.0f} s")
    rec, phases = Recorder(), []  # type: ignore[var-annotated]
    with tempfile.TemporaryDirectory(prefix="bench-metro-") as tmp:
        metro_bundle(city, Path(tmp))
        env = {
            "SD_CITIES_DIR": tmp,
            "SD_WORKER_RATE_PER_HOUR": str(METRO_RATE_PER_HOUR),
            "SD_WORKER_TASKS": str(METRO_TASKS),
        }
        with service(METRO, env, log) as svc:
            load = MetroLoad(svc, city, rec)
            for _ in range(2):  # the first epochs load the city's state and compile: untimed
                load.post(record=False)
            load_before = os.getloadavg()
            done = threading.Event()
            ctl = alternate(
                lambda: quiet_phase(svc, quiet_s, phases, done),
                lambda: bounded_solve_phase(svc, solve_s, phases, log),
                rounds,
                done,
            )
            while not done.is_set():
                load.post()
                done.wait(gap_s)  # the worker's runs go on between epochs, as between a platform's
                if load.posted % 10 == 0:
                    log(f"metro250k: {load.posted} epochs, {len(phases)} phases")
            ctl.join()
            load_after = os.getloadavg()
    return {
        **summarize(rec, phases),
        "epochs_posted": load.posted,
        "loadavg_before": list(load_before),
        "loadavg_after": list(load_after),
        "rounds": rounds,
        "quiet_s": quiet_s,
        "solve_s": solve_s,
        "gap_s": gap_s,
        "nodes": city.network.n_nodes,
    }


# ---------------------------------------------------------------------------------------------- report


def _rows(res: dict[str, Any]) -> list[str]:
    row = "| {label} | {n} | {p50_ms:.0f} | {p99_ms:.0f} | {max_ms:.0f} |"
    return [
        "| epochs | n | p50 (ms) | p99 (ms) | max (ms) |",
        "|---|---|---|---|---|",
        row.format(label="no solve running (all quiet phases)", **res["without_solve"]),
        row.format(label="a solve running (all solve phases)", **res["during_solve"]),
    ]


def _phase_line(res: dict[str, Any]) -> str:
    parts = []
    for ph in res["phases"]:
        what = "quiet" if ph["kind"] == "quiet" else f"solve (worker CPU {ph['worker_cpu_s']:.0f} s)"
        parts.append(f"{what} {ph['duration_s']:.0f} s, n {ph['n']}, p99 {ph['p99_ms']:.0f} ms")
    return "; ".join(parts)


def _verdict(ratio: float) -> str:
    return (
        f"**{ratio:.2f}x** (target at most {TARGET_RATIO}x: {'met' if ratio <= TARGET_RATIO else 'NOT met'})"
    )


def _load(res: dict[str, Any]) -> str:
    b, a = res["loadavg_before"], res["loadavg_after"]
    return (
        f"load average before / after {', '.join(f'{v:.2f}' for v in b)} / {', '.join(f'{v:.2f}' for v in a)}"
    )


def report_chengdu(res: dict[str, Any]) -> list[str]:
    if res.get("solve_s"):
        what = (
            f"{res['rounds']} solve phases of {res['solve_s']:.0f} s (a requested solve's runs in progress from "
            "an empty run cache, ended by the benchmark)"
        )
        title = "solve phases of runs in progress"
    else:
        walls = ", ".join(f"{s['request_to_published_s']:.0f}" for s in res["solves"])
        what = (
            f"{res['rounds']} whole solves, each from an empty run cache ({res['solves'][0]['runs']} runs; a "
            f"request to its recommendation published: {walls} s)"
        )
        title = "whole solves"
    return [
        f"### The paper's scale: Chengdu, the replay client's days ({title})",
        "",
        *([res["stamp"], ""] if "stamp" in res else []),
        f"{what} between {res['rounds'] + 1} phases of {res['quiet_s']:.0f} s without; "
        f"{res['days_replayed']} days replayed back to back; {_load(res)}.",
        "",
        *_rows(res),
        "",
        f"p99 during a solve / without: {_verdict(res['p99_ratio'])}; p50 {res['p50_ratio']:.2f}x. "
        f"Phase by phase: {_phase_line(res)}.",
    ]


def report_metro(res: dict[str, Any]) -> list[str]:
    return [
        f"### A platform's scale: metro250k ({res['nodes']:,} nodes), 5,000 taxis an epoch",
        "",
        *([res["stamp"], ""] if "stamp" in res else []),
        f"{res['rounds']} solve phases of {res['solve_s']:.0f} s (a requested re-solve's runs in progress, "
        f"ended by the benchmark) between {res['rounds'] + 1} phases of {res['quiet_s']:.0f} s without; "
        f"{res['epochs_posted']} epochs posted, {res['gap_s']:g} s apart (the worker's runs go on between "
        f"them); {_load(res)}.",
        "",
        *_rows(res),
        "",
        f"p99 during a solve / without: {_verdict(res['p99_ratio'])}; p50 {res['p50_ratio']:.2f}x. "
        f"Phase by phase: {_phase_line(res)}.",
    ]


def report(res: dict[str, Any]) -> str:
    out = [
        "## The whole service: epochs while the embedded worker solves, and a solve request to the "
        "recommendation",
        "",
        res["stamp"],
        "",
        "`python -m app run` as `make run` starts it (memory store, the fleet worker inside it: its simulation "
        'runs on 2 local processes at niceness +10, stopped while an epoch is solved; docs/FLEET.md, "When the '
        'worker solves"). Epochs are posted over HTTP (a platform posts one every 200 s; here they come '
        "back to back, or a few seconds apart at the metropolitan scale, so that the runs hold the CPU when an "
        "epoch arrives) while phases alternate in the same run, no solve / a solve / no solve ...; an epoch "
        "counts in a phase when it started and ended inside it. The target: the epoch p99 with a solve "
        f"running at most {TARGET_RATIO}x the p99 without (module docstring of `bench/bench_fleet_service.py`).",
        "",
    ]
    for key in ("chengdu", "chengdu_whole"):
        if key in res:
            out += [*report_chengdu(res[key]), ""]
    for key in ("metro", "metro_before"):  # metro_before: an earlier measurement set beside it
        if key in res:
            out += [*report_metro(res[key]), ""]
    out += [
        "Reading: a phase's p99 over a few epochs is its largest epoch (the metropolitan phases hold 2-6 "
        "each), so a ratio there moves with one slow epoch; the worker's CPU seconds per solve phase say "
        "how much the runs ran beside the epochs (on a machine loaded by other work, processes at niceness "
        "+10 get little).",
    ]
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--scale", choices=("chengdu", "metro", "both"), default="both")
    ap.add_argument("--rounds", type=int, default=2, help="solves (solve phases) per scale")
    ap.add_argument("--quiet-s", type=float, default=90.0, help="seconds of each phase without a solve")
    ap.add_argument("--metro-solve-s", type=float, default=120.0, help="seconds of each metro solve phase")
    ap.add_argument(
        "--chengdu-solve-s",
        type=float,
        default=None,
        help="chengdu solve phases of this many seconds of runs",
    )
    ap.add_argument("--metro-gap-s", type=float, default=5.0, help="seconds between two metro epochs")
    ap.add_argument("--json-out", type=Path, default=JSON_OUT, help="where the measurement is written")
    ap.add_argument("--no-screenshot", action="store_true", help="do not save the dashboard screenshot")
    ap.add_argument("--no-write", action="store_true", help="print the section, write nothing")
    ap.add_argument("--report-only", type=Path, nargs="+", default=None, help="the section from these JSONs")
    args = ap.parse_args()
    if args.report_only is not None:
        res: dict[str, Any] = {}
        for path in args.report_only:  # one file per scale when they were measured apart: each its stamp
            part = json.loads(path.read_text())
            for scale in ("chengdu", "metro", "metro_before"):
                if scale in part:
                    key = "chengdu_whole" if scale == "chengdu" and not part[scale].get("solve_s") else scale
                    res[key] = {"stamp": part["stamp"], **part[scale]}
        res["stamp"] = stamp(
            f"python -m bench.bench_fleet_service --report-only {' '.join(map(str, args.report_only))}"
        )
    else:
        res = {"stamp": stamp(" ".join(["python -m bench.bench_fleet_service", *sys.argv[1:]]))}

        def log(m: str) -> None:
            print(m, flush=True)

        if args.scale in ("chengdu", "both"):
            shot = not (args.no_screenshot or args.no_write)
            res["chengdu"] = measure_chengdu(args.rounds, args.quiet_s, args.chengdu_solve_s, shot, log)
            log(json.dumps({k: v for k, v in res["chengdu"].items() if k != "phases"}, indent=1))
        if args.scale in ("metro", "both"):
            res["metro"] = measure_metro(args.rounds, args.quiet_s, args.metro_solve_s, args.metro_gap_s, log)
            log(json.dumps({k: v for k, v in res["metro"].items() if k != "phases"}, indent=1))
        if not args.no_write:
            args.json_out.write_text(json.dumps(res, indent=2) + "\n")
    if args.no_write:
        print(report(res))
    else:
        print(write_section("fleet-service", report(res)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
