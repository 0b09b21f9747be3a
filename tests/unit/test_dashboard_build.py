"""The built dashboard committed under app/static/dashboard/ is the build of the committed front-end source
(frontend/): same digest of the inputs as frontend/build.mjs computes, and every asset the page loads is
there. A fresh clone serves the page without npm; this keeps the two from drifting apart."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FRONTEND = ROOT / "frontend"
BUILT = ROOT / "app" / "static" / "dashboard"


def _digest(inputs: list[str]) -> str:
    h = hashlib.sha256()
    for path in inputs:
        h.update(f"{path}\0".encode())
        h.update((FRONTEND / path).read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def test_the_built_assets_match_the_source() -> None:
    stamp = json.loads((BUILT / "assets" / "build.json").read_text())
    sources = sorted(f"src/{p.name}" for p in (FRONTEND / "src").iterdir())
    assert stamp["inputs"] == ["build.mjs", "index.html", "package.json", "package-lock.json", *sources], (
        "frontend/ gained or lost a source file since the last build: run `make dashboard`"
    )
    assert stamp["sha256"] == _digest(stamp["inputs"]), (
        "frontend/ changed since app/static/dashboard/ was built: run `make dashboard` and commit the result"
    )
    assert (BUILT / "index.html").read_bytes() == (FRONTEND / "index.html").read_bytes()


def test_the_page_loads_only_assets_that_ship() -> None:
    page = (BUILT / "index.html").read_text()
    refs = [r for r in re.findall(r'(?:src|href)="([^"]+)"', page) if r != "data:,"]  # the empty favicon
    assert sorted(refs) == ["dashboard/assets/dashboard.css", "dashboard/assets/dashboard.js"]
    for ref in refs:
        assert (BUILT / ref.removeprefix("dashboard/")).stat().st_size > 1000
    # no other host is named but XML namespaces and Leaflet's attribution link (no CDN, no tile server);
    # the browser test checks that every request the running page makes goes to the service itself
    allowed = {"http://www.w3.org", "https://leafletjs.com"}
    for name in ("dashboard.js", "dashboard.css"):
        hosts = set(re.findall(r"https?://[A-Za-z0-9.-]+", (BUILT / "assets" / name).read_text()))
        assert hosts <= allowed, f"{name} names {sorted(hosts - allowed)}"
