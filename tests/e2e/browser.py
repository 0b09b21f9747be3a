"""The browser the dashboard tests drive: Debian's chromium under Playwright, never skipped
(``tests/e2e/conftest.py`` gives it to the tests as the ``browser`` fixture; the fleet service benchmark
takes its screenshot in it too)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["CHROMIUM", "CHROMIUM_ARGS", "MISSING"]

CHROMIUM = Path("/usr/bin/chromium")
# as root, without a GPU, on a machine whose only network is loopback and the package registries
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
MISSING = (
    f"{CHROMIUM} is missing: the dashboard is tested in Debian's chromium, never skipped; "
    "run `bash scripts/install_browser.sh` (apt-get install chromium, as root)"
)
