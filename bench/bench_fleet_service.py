"""The whole service on one command: time from a solve request to the recommendation, and epoch latency while
the embedded fleet worker solves against without.

    python -m bench.bench_fleet_service                 # measure, write docs/PERFORMANCE.md, the screenshot
    python -m bench.bench_fleet_service --report-only docs/perf_fleet_service.json

The service is started as `make run` starts it (`python -m app run`: memory store, the fleet worker inside
it, every worker setting at its default), with a token, a free port and a fresh `SD_VAR_DIR` (no cached
simulation runs: the solve simulates all 60 of them). Epochs are the replay client's (`python -m app replay`
defaults: Chengdu scenario 1, 60 + 60 taxis, 85 POI tasks, 72 epochs a day) over HTTP; an epoch's latency is
its HTTP round trip as the client sees it (the body built, the decision read). First `--quiet-days` days
with no solve running, then a solve request, and day after day until the recommendation is published: the
epochs that started and ended while the status showed the solve in progress are the "during a solve" sample.
The dashboard with the recommendation is then opened in Debian's chromium and saved as
docs/figures/dashboard.png (the README shows it).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from app.adapters.city_registry import CityRegistry
from app.entrypoints.replay_client import HttpDispatcher
from app.runs import RunSpec, demand_for, open_bundle, tasks_for
from bench.report import ROOT, stamp, write_section
from services.sim.demand import demand_on_date
from services.sim.engine import SimConfig, simulate
from tests.e2e.service import start_process, stop, wait_ready

CITY = "chengdu"
TOKEN = "bench-fleet-admin-token"
JSON_OUT = ROOT / "docs" / "perf_fleet_service.json"
SCREENSHOT = ROOT / "docs" / "figures" / "dashboard.png"
FIRST_DATE = dt.date(2026, 10, 1)


@dataclass
class Timeline:
    """Each epoch's (start, end) on the monotonic clock and round trip; when the solve ran."""

    epochs: list[tuple[float, float]] = field(default_factory=list)
    solving: list[tuple[float, bool]] = field(default_factory=list)  # (when, a solve was in progress)
    requested_at: float | None = None
    published_at: float | None = None


class TimedDispatcher(HttpDispatcher):
    """The replay client, recording when each epoch's POST started and ended."""

    def __init__(self, client: httpx.Client, timeline: Timeline) -> None:
        bundle = open_bundle(CityRegistry().bundle_dir(CITY))
        super().__init__(client, CITY, bundle.city)
        self.timeline = timeline

    def _request(self, method: str, url: str, what: str, **kwargs: Any) -> httpx.Response:
        started = time.monotonic()
        r = super()._request(method, url, what, **kwargs)
        if method == "POST" and url.endswith("/epochs"):
            self.timeline.epochs.append((started, time.monotonic()))
        return r


def replay_day(client: httpx.Client, timeline: Timeline, day: int) -> None:
    """One day of the replay defaults on date FIRST_DATE + day (demand day ``day`` of the generator)."""
    spec = RunSpec(CITY, 1, 60, 60, 0, day, True, False, 85)
    bundle = open_bundle(CityRegistry().bundle_dir(CITY))
    date = (FIRST_DATE + dt.timedelta(days=day)).isoformat()
    demand = demand_on_date(demand_for(spec, bundle), bundle.city.horizon, date)
    prefix = f"bench{day}-"
    tasks = tasks_for(spec, bundle, demand.date, prefix)
    config = SimConfig(n_instrumented=60, n_ordinary=60, n_tasks=85, seed=0, id_prefix=prefix)
    simulate(bundle.city, demand, tasks, config, TimedDispatcher(client, timeline))


def watch(url: str, timeline: Timeline, done: threading.Event) -> None:
    """Poll the status every 0.25 s: when a solve is in progress, when the recommendation appears."""
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as api:
        while not done.is_set():
            st = api.get(f"/v1/cities/{CITY}/fleet/status").json()
            now = time.monotonic()
            timeline.solving.append((now, st["solving"] is not None))
            last = st["last_solve"]
            if timeline.requested_at is not None and last and last["status"] == "published":
                timeline.published_at = now
                done.set()
            done.wait(0.25)


def percentiles(values: list[float]) -> dict[str, float]:
    a = np.asarray(values) * 1000.0
    return {
        "n": int(a.size),
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "mean_ms": float(a.mean()),
    }


def during(timeline: Timeline, start: float, end: float) -> bool:
    """Whether every status poll within [start, end] (and the last one before it) showed a solve running."""
    polls = [s for t, s in timeline.solving if start <= t <= end]
    before = [s for t, s in timeline.solving if t < start]
    return bool(before) and before[-1] and all(polls)


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


def measure(quiet_days: int, log: Callable[[str], None]) -> dict[str, Any]:
    var = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    proc, url = start_process(
        {"SD_STORE": "memory", "SD_VAR_DIR": str(var), "SD_LOG_LEVEL": "info"},
        {TOKEN: ["read", "dispatch", "admin"]},
    )
    try:
        wait_ready(url, proc)
        client = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=300)
        st = client.get(f"/v1/cities/{CITY}/fleet/status").json()
        assert st["worker"]["seen"] and st["worker"]["workers"][0]["embedded"], st
        timeline = Timeline()
        done = threading.Event()
        watcher = threading.Thread(target=watch, args=(url, timeline, done), daemon=True)
        watcher.start()
        day = 0
        for _ in range(quiet_days):
            replay_day(client, timeline, day)
            log(f"quiet day {day}: {len(timeline.epochs)} epochs so far")
            day += 1
        quiet_end = time.monotonic()
        load_before = os.getloadavg()
        timeline.requested_at = time.monotonic()
        r = client.post(f"/v1/cities/{CITY}/fleet/solve")
        assert r.status_code == 202, r.text
        n_quiet = len(timeline.epochs)
        while not done.is_set():
            replay_day(client, timeline, day)
            log(f"day {day} during the solve: {len(timeline.epochs) - n_quiet} epochs")
            day += 1
        watcher.join()
        load_after = os.getloadavg()
        n_during = len(timeline.epochs)
        after_start = time.monotonic()
        for _ in range(quiet_days):  # open POI tasks pile up day after day: quiet days after it too
            replay_day(client, timeline, day)
            log(f"quiet day {day} after the solve")
            day += 1
        rec = client.get(f"/v1/cities/{CITY}/fleet/recommendation").json()
        quiet = [e - s for s, e in timeline.epochs[:n_quiet] if e <= quiet_end]
        solving = [e - s for s, e in timeline.epochs[n_quiet:n_during] if during(timeline, s, e)]
        after = [e - s for s, e in timeline.epochs[n_during:] if s >= after_start]
        assert timeline.published_at is not None
        screenshot(url)
        client.close()
        return {
            "request_to_recommendation_s": timeline.published_at - timeline.requested_at,
            "solve_wall_s": rec["solve"]["wall_s"],
            "runs": rec["solve"]["runs"],
            "cached_runs": rec["solve"]["cached_runs"],
            "jobs": rec["solve"]["jobs"],
            "chosen": rec["chosen"],
            "subsidy": rec["subsidy_cny_per_vehicle_hour"],
            "without_solve": percentiles(quiet),
            "during_solve": percentiles(solving),
            "without_solve_after": percentiles(after),
            "loadavg_before": list(load_before),
            "loadavg_after": list(load_after),
            "days_replayed": day,
            "stamp": stamp("python -m bench.bench_fleet_service"),
        }
    finally:
        stop(proc)


def report(res: dict[str, Any]) -> str:
    q, s, a = res["without_solve"], res["during_solve"], res["without_solve_after"]
    row = "| {label} | {n} | {p50_ms:.0f} | {p99_ms:.0f} | {max_ms:.0f} | {mean_ms:.0f} |"
    return "\n".join(
        [
            "## The whole service: a solve request to the recommendation, and epochs while it solves",
            "",
            res["stamp"],
            "",
            "`python -m app run` as `make run` starts it (memory store, the fleet worker inside it, every worker "
            "setting at its default: 6 sizes x M = 10 synthetic days = 60 whole-day runs on 2 processes at "
            f"niceness +10), a fresh run cache. A solve request (`POST .../fleet/solve`) to the recommendation "
            f"published: **{res['request_to_recommendation_s']:.0f} s** ({res['runs']} runs, {res['cached_runs']} "
            f"cached, the solve itself {res['solve_wall_s']:.0f} s on {res['jobs']} processes; chosen "
            f"{res['chosen']} at ζ = {res['subsidy']:g}). Load average before / after: "
            f"{', '.join(f'{v:.2f}' for v in res['loadavg_before'])} / "
            f"{', '.join(f'{v:.2f}' for v in res['loadavg_after'])}.",
            "",
            "Epoch HTTP round trips (the replay client's days: 60 + 60 taxis, ~140 requests an hour, 85 POI "
            "tasks a day, which stay open until served: later days carry more), with no solve running before "
            "the request, while the worker's runs ran, and with no solve running after it:",
            "",
            "| epochs | n | p50 (ms) | p99 (ms) | max (ms) | mean (ms) |",
            "|---|---|---|---|---|---|",
            row.format(label="no solve running (before)", **q),
            row.format(label="during the solve", **s),
            row.format(label="no solve running (after)", **a),
        ]
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quiet-days", type=int, default=2, help="days replayed before the solve request")
    ap.add_argument("--report-only", type=Path, default=None, help="rewrite the section from this JSON")
    args = ap.parse_args()
    if args.report_only is not None:
        res = json.loads(args.report_only.read_text())
    else:
        res = measure(args.quiet_days, lambda m: print(m, flush=True))
        JSON_OUT.write_text(json.dumps(res, indent=2) + "\n")
    print(write_section("fleet-service", report(res)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
