"""The access log of a real ``python -m app run``: every request of a platform's traffic is in it (a
replayed day's every epoch, hundreds of distinct requests in a few seconds, each with its credential-like
query values blanked); one client's storm of one failing request is cut down and the next line kept says how
many lines were dropped."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.e2e.service import ROOT, start_process, stop, wait_ready

pytestmark = pytest.mark.slow

TOKEN = "tok-access-log-test-0001"
SUPPRESSED = re.compile(r" \[(\d+) similar requests suppressed\]$")


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    log_file = tmp_path_factory.mktemp("access") / "service.log"
    env = {"SD_STORE": "memory", "SD_LOG_LEVEL": "info", "SD_WORKER_EMBEDDED": "off"}
    proc, url = start_process(env, {TOKEN: ["read", "dispatch"]}, log_file=log_file)
    try:
        wait_ready(url, proc)
        yield url, log_file
    finally:
        stop(proc)


def _lines(log_file: Path, needle: str) -> list[str]:
    return [line for line in log_file.read_text(errors="replace").splitlines() if needle in line]


def test_every_epoch_of_a_replayed_day_is_in_the_access_log(served: tuple[str, Path]) -> None:
    url, log_file = served
    done = subprocess.run(
        [sys.executable, "-m", "app", "replay", "--url", url, "--token", TOKEN, "--date", "2026-03-02"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    log = httpx.get(
        f"{url}/v1/cities/chengdu/epochs", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=10
    ).json()
    n_epochs = int(log["committed"])
    assert n_epochs == 72  # the horizon's epochs: four hours, 200 s apart
    lines = _lines(log_file, '"POST /v1/cities/chengdu/epochs HTTP/1.1" 200')
    assert len(lines) == n_epochs


def test_hundreds_of_distinct_requests_all_appear_redacted(served: tuple[str, Path]) -> None:
    url, log_file = served
    headers = {"Authorization": f"Bearer {TOKEN}"}
    with httpx.Client(base_url=url, headers=headers, timeout=10) as client:
        for i in range(200):
            assert client.get(f"/v1/cities/chengdu?token=sd-query-secret-{i}&n={i}").status_code == 200
    text = log_file.read_text(errors="replace")
    for i in range(200):
        assert text.count(f'"GET /v1/cities/chengdu?token=***&n={i} HTTP/1.1" 200') == 1, i
    assert "sd-query-secret" not in text


def test_one_clients_storm_of_a_failing_request_is_cut_and_counted(served: tuple[str, Path]) -> None:
    url, log_file = served
    storm = 1500
    with httpx.Client(base_url=url, timeout=10) as client:  # no token: 401 every time
        for _ in range(storm):
            assert client.get("/v1/cities?token=sd-storm-secret").status_code == 401
        time.sleep(10.5)  # the next window: the next line kept carries the count of the dropped ones
        assert client.get("/v1/cities?token=sd-storm-secret").status_code == 401
    time.sleep(0.5)
    lines = _lines(log_file, '"GET /v1/cities?token=*** HTTP/1.1" 401')
    dropped = [int(m.group(1)) for line in lines if (m := SUPPRESSED.search(line))]
    assert len(lines) < storm / 2  # cut down to the budget (500 lines a client and status class every 10 s)
    assert dropped and len(lines) + sum(dropped) == storm + 1  # every request kept or counted
    assert "sd-storm-secret" not in log_file.read_text(errors="replace")
