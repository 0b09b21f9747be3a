"""A real service process for end-to-end tests: ``python -m app run`` on a free loopback port, on a real
Redis under a key prefix, with the given tokens; ready when ``/readyz`` answers 200."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import httpx

__all__ = ["ROOT", "start_process", "start_service", "wait_ready", "stop", "running_service"]

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_process(
    env: Mapping[str, str],
    tokens: Mapping[str, Sequence[str]],
    *,
    port: int | None = None,
    log_file: Path | None = None,
) -> tuple[subprocess.Popen[bytes], str]:
    """Start ``python -m app run`` with ``SD_*`` settings ``env`` (on top of this environment) and the
    tokens, on ``port`` (a free one by default); its whole output goes to ``log_file`` when given (a file,
    not a pipe: a busy access log never blocks the server on a full pipe), else only stderr is captured."""
    port = port or _free_port()
    full = {
        **os.environ,
        "SD_PORT": str(port),
        "SD_TOKENS": json.dumps({t: list(s) for t, s in tokens.items()}),
        "SD_LOG_LEVEL": "warning",
        **env,
    }
    if log_file is None:
        proc = subprocess.Popen(
            [sys.executable, "-m", "app", "run"],
            cwd=ROOT,
            env=full,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
    else:
        with log_file.open("wb") as out:
            proc = subprocess.Popen(
                [sys.executable, "-m", "app", "run"], cwd=ROOT, env=full, stdout=out, stderr=subprocess.STDOUT
            )
    return proc, f"http://127.0.0.1:{port}"


def start_service(
    redis_url: str, prefix: str, tokens: Mapping[str, Sequence[str]], *, port: int | None = None
) -> tuple[subprocess.Popen[bytes], str]:
    """Start one service process on Redis under ``prefix``; returns it and its base URL (not yet ready)."""
    env = {"SD_STORE": "redis", "SD_REDIS_URL": redis_url, "SD_REDIS_PREFIX": prefix}
    return start_process(env, tokens, port=port)


def wait_ready(url: str, proc: subprocess.Popen[bytes], timeout_s: float = 600.0) -> None:
    """Wait until ``/readyz`` answers 200; raise with the process's stderr when it exits first. Readiness
    waits for start-up's warm-up, which compiles the kernels when numba's cache is cold (minutes)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"service exited: {proc.stderr.read().decode() if proc.stderr else ''}")
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise RuntimeError(f"service not ready within {timeout_s:.0f} s")


def stop(proc: subprocess.Popen[bytes]) -> None:
    """Terminate the process and wait for it."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


@contextmanager
def running_service(redis_url: str, prefix: str, tokens: Mapping[str, Sequence[str]]) -> Iterator[str]:
    """One ready service process for the duration of the block; yields its base URL."""
    proc, url = start_service(redis_url, prefix, tokens)
    try:
        wait_ready(url, proc)
        yield url
    finally:
        stop(proc)
