"""Slow, silent and oversized clients. A connection that never finishes its headers or its body is answered
408 and closed after the deadline, not held forever; headers past the size cap are answered 431 and closed;
connections beyond the cap are refused at once with a 503, not held until the process runs out of
descriptors; a token in a query string never reaches the access log."""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.entrypoints.serve import serve_app_in_thread, serve_in_thread
from app.entrypoints.server import MAX_HEADER_BYTES
from app.settings import Settings
from tests.e2e.service import start_process, stop, wait_ready

CAP = 8


@pytest.fixture(scope="module")
def served() -> Iterator[tuple[str, int, str]]:
    with serve_in_thread(header_timeout_s=1.0, body_timeout_s=1.0, max_connections=CAP) as (url, token):
        yield url, int(url.rsplit(":", 1)[1]), token


def _connect(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port))
    s.settimeout(30)  # the failure mode: the server holds the connection (recv times out)
    return s


def _read_all(s: socket.socket) -> bytes:
    out = b""
    while chunk := s.recv(65536):
        out += chunk
    return out


def test_unfinished_headers_get_408_and_are_closed(served: tuple[str, int, str]) -> None:
    _, port, _ = served
    with _connect(port) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")  # no blank line: the headers never end
        reply = _read_all(s)
    assert reply.startswith(b"HTTP/1.1 408 ") and b'"request_timeout"' in reply


def test_silent_connection_is_closed(served: tuple[str, int, str]) -> None:
    _, port, _ = served
    with _connect(port) as s:
        assert _read_all(s).startswith(b"HTTP/1.1 408 ")


def test_trickled_headers_do_not_reset_the_deadline(served: tuple[str, int, str]) -> None:
    _, port, _ = served
    with _connect(port) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\n")
        got = b""
        for i in range(12):  # a header line every 0.25 s: 3 s in all, the deadline is 1 s
            try:
                s.sendall(f"X-Slow-{i}: 1\r\n".encode())
            except OSError:
                break
            time.sleep(0.25)
        got = _read_all(s)
    assert got.startswith(b"HTTP/1.1 408 ")


def test_headers_past_the_cap_get_431_and_are_closed(served: tuple[str, int, str]) -> None:
    _, port, _ = served
    with _connect(port) as s:
        lines = "".join(f"X-Big-{i}: {'a' * 1000}\r\n" for i in range(MAX_HEADER_BYTES // 1000 + 1))
        s.sendall(f"GET /healthz HTTP/1.1\r\nHost: x\r\n{lines}".encode())  # past the cap, never finished
        reply = _read_all(s)
    assert reply.startswith(b"HTTP/1.1 431 ") and b'"headers_too_large"' in reply


def _slow_app(release: threading.Event) -> Any:
    """An ASGI app that answers ``/slow`` once ``release`` is set, anything else at once (its body read)."""

    async def app(scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            return  # no lifespan: uvicorn carries on without it
        while (await receive()).get("more_body"):
            pass
        while scope["path"] == "/slow" and not release.is_set():
            await asyncio.sleep(0.02)
        await send({"type": "http.response.start", "status": 200, "headers": [(b"content-length", b"2")]})
        await send({"type": "http.response.body", "body": b"ok"})

    return app


def test_headers_pipelined_behind_a_request_in_flight_count_toward_the_cap() -> None:
    """A request's headers streamed while the one before it on the connection is still being served (which
    holds its header deadline off) are capped as well."""
    release = threading.Event()
    settings = Settings.model_validate({"store": "memory", "header_timeout_s": 1.0})
    threading.Timer(3.0, release.set).start()  # the slow request ends after 3 s whatever happens
    with serve_app_in_thread(_slow_app(release), settings) as url, _connect(int(url.rsplit(":", 1)[1])) as s:
        s.sendall(b"GET /slow HTTP/1.1\r\nHost: x\r\n\r\nGET /next HTTP/1.1\r\nHost: x\r\n")
        for i in range(MAX_HEADER_BYTES // 1000 + 1):  # in separate reads, while /slow is served
            time.sleep(0.02)
            s.sendall(f"X-Big-{i}: {'a' * 1000}\r\n".encode())
        reply = _read_all(s)
        served_before = release.is_set()
    assert reply.startswith(b"HTTP/1.1 431 ") and not served_before


def test_a_large_body_and_the_next_request_in_one_read_are_served() -> None:
    """The cap counts header bytes only: a body past it, read together with the start of the next
    request, is not taken for headers."""
    settings = Settings.model_validate({"store": "memory", "header_timeout_s": 1.0})
    body = b"x" * (4 * MAX_HEADER_BYTES)
    post = b"POST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n\r\n" % len(body) + body
    app = _slow_app(threading.Event())
    with serve_app_in_thread(app, settings) as url, _connect(int(url.rsplit(":", 1)[1])) as s:
        s.sendall(post + b"GET /next HTTP/1.1\r\nHost: x\r\n")
        time.sleep(0.2)
        s.sendall(b"Connection: close\r\n\r\n")
        reply = _read_all(s)
    assert reply.count(b"HTTP/1.1 200 ") == 2 and b" 431 " not in reply


def test_headers_within_the_cap_are_served(served: tuple[str, int, str]) -> None:
    _, port, _ = served
    padding = "".join(f"X-Pad-{i}: {'a' * 1000}\r\n" for i in range(MAX_HEADER_BYTES // 1100))
    with _connect(port) as s:
        s.sendall(f"GET /healthz HTTP/1.1\r\nHost: x\r\n{padding}Connection: close\r\n\r\n".encode())
        assert _read_all(s).startswith(b"HTTP/1.1 200 ")


def test_pipelined_requests_are_answered_and_the_next_headers_have_the_deadline(
    served: tuple[str, int, str],
) -> None:
    _, port, _ = served
    with _connect(port) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n" * 3)  # three requests in one send
        reply = _read_all(s)  # their answers, then the fourth's headers never come
    assert reply.count(b"HTTP/1.1 200 ") == 3
    assert reply.rindex(b"HTTP/1.1 408 ") > reply.rindex(b"HTTP/1.1 200 ")


def test_unfinished_body_gets_408(served: tuple[str, int, str]) -> None:
    _, port, token = served
    with _connect(port) as s:
        s.sendall(
            b"POST /v1/dro/worst-case HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            b"Authorization: Bearer " + token.encode() + b"\r\nContent-Length: 100\r\n\r\n"
            b'{"samples": [1'
        )
        reply = _read_all(s)
    assert reply.startswith(b"HTTP/1.1 408 ") and b'"request_timeout"' in reply


def test_connections_beyond_the_cap_are_refused_at_once(served: tuple[str, int, str]) -> None:
    url, port, _ = served
    held = [_connect(port) for _ in range(CAP)]
    try:
        time.sleep(0.2)
        with _connect(port) as extra:
            reply = _read_all(extra)  # answered and closed before the header deadline
        assert reply.startswith(b"HTTP/1.1 503 ") and b"open connections" in reply
    finally:
        for s in held:
            s.close()
    time.sleep(0.2)
    assert httpx.get(f"{url}/healthz", timeout=10).status_code == 200
    # a normal client is not affected by the deadline: keep-alive requests on one connection
    with httpx.Client(base_url=url, timeout=10) as c:
        for _ in range(3):
            assert c.get("/healthz").status_code == 200


def test_query_token_not_in_the_access_log(tmp_path: Path) -> None:
    secret = "sd-secret-in-the-query-0123456789"
    env = {"SD_STORE": "memory", "SD_LOG_LEVEL": "info", "SD_HEADER_TIMEOUT_S": "1"}
    proc, url = start_process(env, {"tok-log-test-0001": ["read"]}, log_file=tmp_path / "service.log")
    try:
        wait_ready(url, proc)
        r = httpx.get(f"{url}/v1/cities?token={secret}&x=1", timeout=10)
        assert r.status_code == 401
        # the CLI's server has the header deadline too
        with _connect(int(url.rsplit(":", 1)[1])) as s:
            s.sendall(b"GET /healthz HTTP/1.1\r\n")
            assert _read_all(s).startswith(b"HTTP/1.1 408 ")
    finally:
        stop(proc)
    log = (tmp_path / "service.log").read_text(errors="replace")
    assert "GET /v1/cities?token=***&x=1 HTTP/1.1" in log, log[-2000:]
    assert secret not in log
