"""Fleet sizing for a city the platform brings, at the fleet it runs, through the API of a real
``python -m app run`` (the embedded worker): a network imported from CSV (no POIs, no recorded requests),
then, before any history, the 409 and the status's "collecting history"; then M operating days of epochs
posted through the API and the platform's tasks registered; then a recommendation sized on those days, on
the ordinary fleet posted, with candidate sizes around the instrumented fleet posted, from where the
recorded fleet stood when each day's horizon opened."""

from __future__ import annotations

import datetime as dt
import subprocess
import sys
import time
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import httpx
import pytest
from playwright.sync_api import Browser, expect

from app.usecases.fleet_history import spread_sizes
from services.city import Horizon
from tests.e2e.service import ROOT, start_process, stop, wait_ready

pytestmark = pytest.mark.slow

ADMIN = "tok-own-city-admin-01"
CITY = "own"
SIDE = 8  # an 8 x 8 street grid, 250 m blocks
N_INSTRUMENTED, N_ORDINARY = 6, 10
M = 2
TZ = "Asia/Shanghai"
HORIZON = Horizon(timezone=TZ, n_intervals=1)  # 08:00-09:00 local, epochs 200 s apart: 18 a day


def node(col: int, row: int) -> int:
    return 1000 + row * SIDE + col


def write_network(directory: Path) -> tuple[Path, Path]:
    """nodes.csv and edges.csv of a two-way street grid near 104.06 E, 30.66 N."""
    nodes, edges = directory / "nodes.csv", directory / "edges.csv"
    dlon, dlat = 250.0 / 95_800.0, 250.0 / 111_320.0
    rows = [
        f"{node(c, r)},{104.06 + c * dlon:.7f},{30.66 + r * dlat:.7f}"
        for r in range(SIDE)
        for c in range(SIDE)
    ]
    nodes.write_text("id,lon,lat\n" + "\n".join(rows) + "\n")
    links = []
    for r in range(SIDE):
        for c in range(SIDE):
            for c2, r2 in ((c + 1, r), (c, r + 1)):
                if c2 < SIDE and r2 < SIDE:
                    links += [f"{node(c, r)},{node(c2, r2)},250", f"{node(c2, r2)},{node(c, r)},250"]
    edges.write_text("u,v,length_m\n" + "\n".join(links) + "\n")
    return nodes, edges


def epoch(day: dt.date, e: int) -> dict[str, Any]:
    """Epoch ``e`` of a day: the whole fleet (instrumented first, each where the platform has it) and two new
    riders."""
    start = dt.datetime.combine(day, dt.time(8), tzinfo=ZoneInfo(TZ))
    when = start + dt.timedelta(seconds=200 * e)
    taxis = [
        {
            "id": f"{'i' if k < N_INSTRUMENTED else 'o'}{k}",
            "location": {"node": node((k * 3 + e) % SIDE, (k * 5) % SIDE)},
            "instrumented": k < N_INSTRUMENTED,
            "status": "vacant",
        }
        for k in range(N_INSTRUMENTED + N_ORDINARY)
    ]
    riders = [
        {
            "id": f"{day}-{e}-{j}",
            "origin": {"node": node((e + j) % SIDE, (2 * e + j) % SIDE)},
            "destination": {"node": node((5 * e + 3 * j) % SIDE, (e + 4) % SIDE)},
            "requested_at": (when - dt.timedelta(seconds=30)).isoformat(),
        }
        for j in range(2)
    ]
    return {"epoch_id": f"{day}-{e:02d}", "time": when.isoformat(), "riders": riders, "taxis": taxis}


def test_an_imported_city_is_sized_on_the_days_and_fleet_it_posted(browser: Browser, tmp_path: Path) -> None:
    nodes, edges = write_network(tmp_path)
    cities = tmp_path / "cities"
    imported = subprocess.run(
        [sys.executable, "-m", "app", "import-city", CITY, "--nodes", str(nodes), "--edges", str(edges),
         "--timezone", TZ, "--intervals", "1", "--out", str(cities)],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert imported.returncode == 0, imported.stderr
    env = {
        "SD_STORE": "memory",
        "SD_CITIES_DIR": str(cities),
        "SD_WORKER_CITIES": f'["{CITY}"]',
        "SD_WORKER_DAYS": str(M),
        "SD_WORKER_JOBS": "1",
        "SD_VAR_DIR": str(tmp_path / "var"),
    }
    proc, url = start_process(env, {ADMIN: ["read", "dispatch", "admin"]})
    try:
        wait_ready(url, proc)
        api = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {ADMIN}"}, timeout=60)
        base = f"/v1/cities/{CITY}"
        assert api.get(base).json()["fleet"]["synthetic_history"] is False
        target = HORIZON.coming_interval(time.time())
        solve_day = HORIZON.local_start(target).date()
        days = [solve_day - dt.timedelta(days=back) for back in range(M, 0, -1)]

        # no history yet: refused, and the status says how far the city is
        r = api.post(f"{base}/fleet/solve")
        assert r.status_code == 409, r.text
        assert r.json()["error"] == "insufficient_history"
        first = (solve_day + dt.timedelta(days=M)).isoformat()
        assert r.json()["history"] == {"days": 0, "needed": M, "first_solve_on": first}
        st = api.get(f"{base}/fleet/status").json()
        assert st["history"]["text"].startswith(f"collecting history: 0 of {M} days"), st
        assert st["history"]["until_then"] == "none" and st["solving"] is None
        page = browser.new_page()
        page.goto(f"{url}/dashboard?poll=2")
        page.fill("#token", ADMIN)
        page.click("#connect")
        page.select_option("#city", CITY)
        expect(page.locator("#fleet-history")).to_contain_text(f"collecting history: 0 of {M} days")
        expect(page.locator("#fleet-history")).to_contain_text(f"a first solve is possible on {first}")

        # the platform's tasks of the day sized for, then its operating days
        start = dt.datetime.combine(solve_day, dt.time(8), tzinfo=ZoneInfo(TZ))
        tasks = [
            {"id": f"poi-{j}", "location": {"node": node(7 - j, j)},
             "scheduled_at": (start + dt.timedelta(seconds=300 + 900 * j)).isoformat()}
            for j in range(3)
        ]  # fmt: skip
        assert api.post(f"{base}/tasks", json=tasks).status_code == 200
        for day in days:
            for e in range(18):
                r = api.post(f"{base}/epochs", json=epoch(day, e))
                assert r.status_code == 200, r.text
        st = api.get(f"{base}/fleet/status").json()
        assert st["history"]["enough"] is True, st

        r = api.post(f"{base}/fleet/solve")
        assert r.status_code == 202, r.text
        request_id = r.json()["request_id"]
        rec = _wait_for(api, f"{base}/fleet/recommendation", request_id)
        expect(page.locator("#fleet-window")).to_contain_text("history: recorded", timeout=30_000)
        expect(page.locator("#fleet-history")).to_be_hidden()
        page.close()
    finally:
        stop(proc)
    window, sim = rec["data_window"], rec["simulation"]
    assert window["source"] == "recorded", window
    assert window["days"] == [d.isoformat() for d in reversed(days)]
    assert window["requests_per_day"] == [36, 36]  # two new riders in each of the 18 epochs
    assert (sim["n0"], sim["n0_source"], sim["posted_ordinary"]) == (N_ORDINARY, "recorded", N_ORDINARY)
    assert rec["sizes"] == list(spread_sizes(N_INSTRUMENTED)) and sim["sizes_source"] == "recorded"
    assert min(rec["sizes"]) < N_INSTRUMENTED < max(rec["sizes"])
    assert sim["posted_instrumented"] == N_INSTRUMENTED and sim["fleet_start"] == "recorded"
    assert sim["tasks_source"] == "registered" and sim["n_tasks"] == 3
    assert rec["chosen"]["dro"] in rec["sizes"]


def _wait_for(api: httpx.Client, path: str, request_id: str, timeout_s: float = 600.0) -> dict[str, Any]:
    """The recommendation published for ``request_id`` (fails with the history's reason if the solve
    failed)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        r = api.get(path)
        if r.status_code == 200 and r.json()["request_id"] == request_id:
            return dict(r.json())
        history = api.get(path.replace("recommendation", "recommendations")).json()["entries"]
        failed = [h for h in history if h["request_id"] == request_id and h["status"] == "failed"]
        assert not failed, failed[0]["reason"]
        time.sleep(0.5)
    raise AssertionError(f"no recommendation for {request_id} within {timeout_s:.0f} s")
