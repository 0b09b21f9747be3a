"""The server's log filters: a flood of one message is cut to a few lines plus a count; credential-like
query values are blanked."""

from __future__ import annotations

import logging

from app.logs import RateLimit, RedactQuery, redact_query


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _record(msg: str, *args: object, name: str = "asyncio") -> logging.LogRecord:
    return logging.LogRecord(name, logging.ERROR, __file__, 1, msg, args, None)


def test_flood_of_one_message_is_cut_and_counted() -> None:
    clock = Clock()
    limit = RateLimit(burst=5, window_s=10.0, clock=clock)
    passed = [
        r
        for r in (_record("socket.accept() out of system resource") for _ in range(10_000))
        if limit.filter(r)
    ]
    assert len(passed) == 5
    assert limit.filter(_record("another message"))  # other templates have their own budget
    clock.now += 10.0
    nxt = _record("socket.accept() out of system resource")
    assert limit.filter(nxt) and nxt.getMessage().startswith("[9995 similar messages suppressed] ")


def test_query_credentials_are_blanked() -> None:
    assert redact_query("/v1/cities?token=abc&interval=2026-11-23T08:00") == (
        "/v1/cities?token=***&interval=2026-11-23T08:00"
    )
    assert (
        redact_query("/x?Access_Token=a&api_key=b&k=c&password=")
        == "/x?Access_Token=***&api_key=***&k=c&password=***"
    )
    assert redact_query("/healthz") == "/healthz"
    rec = _record(
        '%s - "%s %s HTTP/%s" %d', "127.0.0.1:1", "GET", "/v1?token=s3cret", "1.1", 401, name="uvicorn.access"
    )
    assert RedactQuery().filter(rec) and "s3cret" not in rec.getMessage()
