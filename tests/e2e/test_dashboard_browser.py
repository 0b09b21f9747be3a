"""The operator dashboard in a real browser: Debian's chromium driven by Playwright (never skipped).

A real service process on a real Redis is fed a few epochs of Chengdu through the replay client, the fleet
worker's solve publishes two recommendations into the same store, and the page is opened in headless
Chromium. The test types a token, as a person would, and checks what the page shows against the API: the
cells coloured where Lambda > 0 (in the DOM and in the pixels of a screenshot), the route count of the
last epoch (in the panel and on the map), the coverage rate and Gamma, the recommendation's chosen sizes,
a new epoch arriving by polling, the interval slider, and that every request goes to the service itself.
No fleet worker runs beside this service: the page says so, and "Solve now" shows the API's refusal (403
without the admin scope, 503 `no_worker` with it). The README's screenshot comes from
`bench/bench_fleet_service.py`, which runs the whole service with its worker.
"""

from __future__ import annotations

import datetime as dt
import uuid
from collections.abc import Mapping
from io import BytesIO
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import httpx
import numpy as np
from PIL import Image
from playwright.sync_api import Browser, ConsoleMessage, Page, Response, expect

from app.adapters.city_registry import CityRegistry
from app.adapters.redis_store import RedisStore
from app.entrypoints.replay_client import HttpDispatcher
from app.runs import RunCache, Runner
from app.schemas.fleet import render_recommendation
from app.usecases.fleet_history import SizingConfig
from app.usecases.fleet_solve import FleetSolver
from services.city import City
from services.citydata import load_city
from services.model import Rider, RiderId, Snapshot, Task, TaskId, Taxi, TaxiId
from tests.e2e.service import ROOT, running_service

CITY = "chengdu"
SHANGHAI = ZoneInfo("Asia/Shanghai")
READ, WRITE, ADMIN = "dash-read-token-0001", "dash-write-token-001", "dash-admin-token-001"
T0 = dt.datetime(2026, 11, 23, 8, 40, tzinfo=SHANGHAI)
HEAT = ["#ffffb2", "#fed976", "#feb24c", "#fd8d3c", "#fc4e2a", "#e31a1c", "#b10026"]  # the page's scale
MAP_BACKGROUND = (0xFB, 0xFB, 0xF8)
CELL_OPACITY = 0.75


def _scenario(city: City) -> tuple[list[Task], list[Snapshot]]:
    """Seeded: 10 POI tasks opening one every 100 s from 08:39; five epochs 200 s apart from 08:40 (their
    trips run on into the 09:00 interval) of 24 taxis (half instrumented) at random nodes, 4-7 riders each."""
    rng = np.random.default_rng(2026)
    n = city.network.n_nodes
    start = T0.timestamp()
    tasks = [Task(TaskId(f"poi{i}"), int(rng.integers(n)), start - 60.0 + 100.0 * i) for i in range(10)]
    snapshots = []
    for e in range(5):
        now = start + 200.0 * e
        riders = tuple(
            Rider(RiderId(f"r{e}-{j}"), int(rng.integers(n)), int(rng.integers(n)), now - 30.0)
            for j in range(int(rng.integers(4, 8)))
        )
        taxis = tuple(
            Taxi(TaxiId(f"t{k:02d}"), int(rng.integers(n)), k < 12, bool(rng.random() < 0.8))
            for k in range(24)
        )
        snapshots.append(Snapshot(f"e{e:02d}", now, riders, taxis))
    return tasks, snapshots


def _publish_recommendations(redis_url: str, prefix: str, cache: Path) -> None:
    """What the hourly worker does before 08:00 and 09:00: two solves on a tiny configuration."""
    store = RedisStore(redis_url, prefix=prefix)
    try:
        hours = [dt.datetime(2026, 11, 23, h, tzinfo=SHANGHAI).timestamp() for h in (7, 8)]
        clock = {"t": hours[0]}
        config = SizingConfig(sizes=(2, 4, 6), days=3, n0=4, n_tasks=3, rate_per_hour=10.0, lookback_days=9)
        sizing = FleetSolver(
            store,
            Runner(RunCache(cache)),
            config,
            render=render_recommendation,
            cities=CityRegistry(),
            clock=lambda: clock["t"],
        )
        city = load_city(ROOT / "app" / "data" / "cities" / CITY)
        for t in hours:
            clock["t"] = t
            outcome = sizing.solve(CITY, city.horizon.interval_of(t + 3600.0))
            assert outcome.status == "published", outcome
    finally:
        store.close()


def _hex(colour: str) -> tuple[int, int, int]:
    return int(colour[1:3], 16), int(colour[3:5], 16), int(colour[5:7], 16)


def _over_background(colour: str) -> tuple[int, int, int]:
    """What a cell's fill looks like on the map's background at the page's opacity."""
    (r, g, b), (br, bg, bb) = _hex(colour), MAP_BACKGROUND
    a = CELL_OPACITY
    return round(a * r + (1 - a) * br), round(a * g + (1 - a) * bg), round(a * b + (1 - a) * bb)


def _dominant(image: Image.Image, box: Mapping[str, Any]) -> tuple[int, int, int]:
    """The most frequent colour in the middle 60 % of an element's box (away from borders and edges)."""
    x, y, w, h = box["x"], box["y"], box["width"], box["height"]
    crop = image.crop((int(x + 0.2 * w), int(y + 0.2 * h), int(x + 0.8 * w), int(y + 0.8 * h)))
    rgb = crop.convert("RGB")
    counted: list[tuple[int, Any]] = rgb.getcolors(maxcolors=rgb.width * rgb.height) or []
    _, (r, g, b) = max(counted, key=lambda c: c[0])
    return int(r), int(g), int(b)


def _close(a: tuple[int, int, int], b: tuple[int, int, int], tol: int = 4) -> bool:
    return all(abs(x - y) <= tol for x, y in zip(a, b, strict=True))


def _connect(page: Page, token: str) -> None:
    page.fill("#token", token)
    page.click("#connect")


def test_the_dashboard_shows_coverage_routes_and_the_recommendation(
    redis_url: str, browser: Browser, tmp_path: Path
) -> None:
    prefix = f"dash{uuid.uuid4().hex[:10]}"
    city = load_city(ROOT / "app" / "data" / "cities" / CITY)
    tasks, snapshots = _scenario(city)
    tokens = {READ: ["read"], WRITE: ["read", "dispatch"], ADMIN: ["read", "admin"]}
    with running_service(redis_url, prefix, tokens) as url:
        api = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {WRITE}"}, timeout=60)
        replay = HttpDispatcher(api, CITY, city)
        replay.add_tasks(tasks)
        for snapshot in snapshots[:-1]:
            replay.epoch(snapshot)
        _publish_recommendations(redis_url, prefix, tmp_path / "runs")

        def expected() -> dict[str, Any]:
            last = api.get(f"/v1/cities/{CITY}/epochs").json()["last"]["epoch_id"]
            epoch = api.get(f"/v1/cities/{CITY}/epochs/{last}").json()
            label = epoch["stats"]["interval"]
            coverage = api.get(f"/v1/cities/{CITY}/coverage", params={"interval": label}).json()
            return {"epoch": epoch, "coverage": coverage}

        want = expected()
        epoch, coverage = want["epoch"], want["coverage"]
        n_routes = len(epoch["rider_matches"]) + len(epoch["task_assignments"])
        assert (
            n_routes > 0 and coverage["n_cells_covered"] > 0
        )  # the scenario gives the page something to show
        rec = api.get(f"/v1/cities/{CITY}/fleet/recommendation").json()

        context = browser.new_context(viewport={"width": 1400, "height": 1000}, timezone_id="Asia/Shanghai")
        page = context.new_page()
        page.clock.set_fixed_time(T0 + dt.timedelta(minutes=15))  # a steady "updated at" in the screenshot
        requests: list[str] = []
        problems: list[str] = []
        refused: list[tuple[int, str]] = []
        page.on("request", lambda r: requests.append(r.url))
        page.on("pageerror", lambda e: problems.append(f"page error: {e}"))

        def console(msg: ConsoleMessage) -> None:
            # the browser also logs every 4xx answer; those are checked one by one below
            if msg.type == "error" and not msg.text.startswith("Failed to load resource"):
                problems.append(f"console: {msg.text}")

        def response(r: Response) -> None:
            if r.status >= 400:
                refused.append((r.status, r.url.removeprefix(url).split("?")[0]))

        page.on("console", console)
        page.on("response", response)
        page.goto(f"{url}/dashboard?poll=2")

        # a wrong token is refused with the API's own message, and the page stays on the login
        _connect(page, "not-a-token-000001")
        expect(page.locator("#error")).to_contain_text("unknown bearer token (401 unauthorized)")
        expect(page.locator("#login")).to_be_visible()

        _connect(page, READ)
        expect(page.locator("#epoch-id")).to_have_text(epoch["epoch_id"])
        expect(page.locator("#error")).to_be_hidden()
        expect(page.locator("#updated")).to_have_text("updated at 08:55:00 · polling every 2 s")

        # the latest epoch's routes: the count in the panel and the lines on the map
        expect(page.locator("#route-count")).to_have_text(str(n_routes))
        expect(page.locator("#poi-routes")).to_have_text(str(len(epoch["task_assignments"])))
        expect(page.locator("path.route")).to_have_count(n_routes)

        # coverage of the epoch's interval: the numbers, and one coloured cell per cell with Lambda > 0
        expect(page.locator("#coverage-rate")).to_have_text(f"{100 * coverage['coverage_rate']:.1f} %")
        expect(page.locator("#gamma")).to_have_text(f"{coverage['gamma_so_far']:.4f}")
        expect(page.locator("#cells-sensed")).to_have_text(
            f"{coverage['n_cells_covered']} of {coverage['n_cells_touched']}"
        )
        sensed = page.locator("path.cell.sensed")
        expect(sensed).to_have_count(coverage["n_cells_covered"])
        fills = sensed.evaluate_all(
            "els => els.map(e => [e.getAttribute('fill'), e.getAttribute('fill-opacity')])"
        )
        assert {f for f, _ in fills} <= set(HEAT) and {o for _, o in fills} == {str(CELL_OPACITY)}
        top = max(c["count"] for c in coverage["cells"])
        assert fills.count([HEAT[-1], str(CELL_OPACITY)]) == sum(c["count"] == top for c in coverage["cells"])

        # the recommendation's numbers
        chosen = rec["chosen"]
        expect(page.locator("#fleet-dro-rh")).to_have_text(str(chosen["dro_rh"]))
        expect(page.locator("#fleet-dro")).to_have_text(str(chosen["dro"]))
        expect(page.locator("#fleet-deterministic")).to_have_text(str(chosen["deterministic"]))
        target = rec["completion_target"]
        expect(page.locator("#fleet-target")).to_have_text("none" if target is None else str(target))
        expect(page.locator("#fleet-hour")).to_have_text(rec["interval"].replace("T", " "))
        expect(page.locator("#history-count")).to_have_text("2")
        # no worker beside this service: the page says so, and a solve request is refused, not queued
        expect(page.locator("#fleet-worker")).to_contain_text("no fleet worker (never seen)")
        page.click("#solve-now")
        expect(page.locator("#solve-answer")).to_contain_text("lacks the 'admin' scope (403 forbidden)")

        # what a person sees: in the screenshot, a sensed cell shows its heat colour, an unsensed one the map
        shot = Image.open(BytesIO(page.screenshot()))
        boxes = sensed.evaluate_all(
            "els => els.map(e => [e.getBoundingClientRect().toJSON(), e.getAttribute('fill')])"
        )
        seen = [(_dominant(shot, box), _over_background(fill)) for box, fill in boxes]
        assert sum(_close(got, want) for got, want in seen) >= 0.9 * len(seen), seen
        # read in one evaluation: the page re-renders its cells at every poll, so an element found in one
        # step may be gone in the next (the cells' places do not change with the same coverage)
        blank = page.locator("path.cell:not(.sensed)").evaluate_all(
            "els => els.map(e => e.getBoundingClientRect().toJSON())"
        )
        drawn = [box for box in blank if box["width"] > 0 and box["height"] > 0]
        assert len(drawn) == len(blank)
        if drawn:
            assert _close(_dominant(shot, drawn[0]), MAP_BACKGROUND)

        # a new epoch arrives by polling: its id, its routes
        replay.epoch(snapshots[-1])
        want = expected()
        n_routes = len(want["epoch"]["rider_matches"]) + len(want["epoch"]["task_assignments"])
        expect(page.locator("#epoch-id")).to_have_text(snapshots[-1].epoch_id, timeout=15_000)
        expect(page.locator("#route-count")).to_have_text(str(n_routes))
        expect(page.locator("path.route")).to_have_count(n_routes)
        expect(page.locator("path.cell.sensed")).to_have_count(want["coverage"]["n_cells_covered"])
        page.screenshot(path=str(tmp_path / "dashboard.png"), full_page=True)

        # the slider: the next interval (the trips run on into it) shows that interval's cells
        label = want["epoch"]["stats"]["interval"]
        slider = page.locator("#interval")
        position = int(slider.input_value())
        later = city.horizon.label(want["epoch"]["stats"]["interval_key"] + 1)
        other = api.get(f"/v1/cities/{CITY}/coverage", params={"interval": later}).json()
        assert other["interval"] == later != label
        slider.fill(str(position + 1))
        expect(page.locator("#follow")).not_to_be_checked()
        expect(page.locator("#coverage-interval")).to_contain_text(later.replace("T", " "))
        expect(page.locator("#interval-label")).to_contain_text(later.replace("T", " "))
        expect(page.locator("path.cell.sensed")).to_have_count(other["n_cells_covered"])
        expect(page.locator("#coverage-rate")).to_have_text(f"{100 * other['coverage_rate']:.1f} %")

        # another city: nothing of Chengdu's stays on the map; nothing committed or recommended there yet
        page.select_option("#city", "manhattan")
        expect(page.locator("#network-size")).to_contain_text("4197 nodes")
        expect(page.locator("#epoch-id")).to_have_text("–")
        expect(page.locator("#epoch-count")).to_have_text("0")
        expect(page.locator("path.route")).to_have_count(0)
        expect(page.locator("path.cell.sensed")).to_have_count(0)
        expect(page.locator("#fleet-none")).to_be_visible()
        expect(page.locator("#error")).to_be_hidden()

        # an admin asks for a solve: 503 no_worker, with how to start a worker; nothing was queued
        page.click("#logout")
        _connect(page, ADMIN)
        expect(page.locator("#epoch-id")).to_have_text(snapshots[-1].epoch_id)
        page.click("#solve-now")
        answer = page.locator("#solve-answer")
        expect(answer).to_contain_text("no fleet worker serving 'chengdu' has been seen")
        expect(answer).to_contain_text("python -m app worker")
        expect(answer).to_contain_text("(503 no_worker)")
        status = api.get(f"/v1/cities/{CITY}/fleet/status").json()
        assert status["pending_request"] is None and status["worker"]["seen"] is False

        context.close()
        api.close()
    assert problems == []
    # the wrong token; Manhattan's recommendation before the worker published one (the page says so); the
    # solve requests: without the admin scope, and with it but no worker
    assert sorted(set(refused)) == [
        (401, "/v1/cities"),
        (403, f"/v1/cities/{CITY}/fleet/solve"),
        (404, "/v1/cities/manhattan/fleet/recommendation"),
        (503, f"/v1/cities/{CITY}/fleet/solve"),
    ]
    assert requests and all(u.startswith(f"{url}/") for u in requests), sorted(set(requests))
