"""Fixtures of the end-to-end tests: the headless browser of the dashboard tests."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

from tests.e2e.browser import CHROMIUM, CHROMIUM_ARGS, MISSING

if TYPE_CHECKING:
    from playwright.sync_api import Browser


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    """Debian's chromium, headless, for one test module (a missing chromium fails the test)."""
    from playwright.sync_api import expect, sync_playwright

    # What the page shows waits on the service's answers: seconds on a machine kept busy by other work,
    # so a check waits up to 30 s for it (the checks themselves are unchanged).
    expect.set_options(timeout=30_000)
    if not CHROMIUM.exists():
        pytest.fail(MISSING)
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        yield b
        b.close()
