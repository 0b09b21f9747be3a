"""The server's log filters: a flood of one message, or one client's storm of one status class in the
access log, is cut to a budget plus a count shown on the next line kept; other traffic is kept whole;
credential-like query values are blanked."""

from __future__ import annotations

import logging

from app.logs import AccessFormatter, AccessRateLimit, AppFormatter, RateLimit, RedactQuery, redact_query


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _record(msg: str, *args: object, name: str = "asyncio") -> logging.LogRecord:
    return logging.LogRecord(name, logging.ERROR, __file__, 1, msg, args, None)


def _access(client: str, path: str, status: int) -> logging.LogRecord:
    return _record('%s - "%s %s HTTP/%s" %d', client, "GET", path, "1.1", status, name="uvicorn.access")


def test_flood_of_one_message_is_cut_and_counted() -> None:
    clock = Clock()
    limit = RateLimit(burst=5, window_s=10.0, clock=clock)
    passed = [
        r
        for r in (_record("socket.accept() out of system resource") for _ in range(10_000))
        if limit.filter(r)
    ]
    assert len(passed) == 5
    assert limit.filter(_record("another message"))  # other messages have their own budget
    clock.now += 10.0
    nxt = _record("socket.accept() out of system resource")
    assert limit.filter(nxt)
    line = AppFormatter("%(levelname)s %(name)s: %(message)s").format(nxt)
    assert (
        line == "ERROR asyncio: socket.accept() out of system resource [9995 identical messages suppressed]"
    )
    assert limit.filter(_record("socket.accept() out of system resource"))
    assert not AppFormatter("%(message)s").format(passed[0]).endswith("suppressed]")


def test_one_template_with_other_arguments_is_not_a_flood() -> None:
    limit = RateLimit(burst=5, window_s=10.0, clock=Clock())
    template = "fleet %s: solve failed, last good recommendation kept: %s"
    records = [
        _record(template, city, "no tasks", name="app.worker") for _ in range(5) for city in ("a", "b")
    ]
    assert all(limit.filter(r) for r in records)  # 5 lines of each city, 10 of the template
    assert not limit.filter(_record(template, "a", "no tasks", name="app.worker"))  # a's sixth
    assert limit.filter(_record(template, "a", "another reason", name="app.worker"))


def test_access_log_keeps_distinct_traffic_and_cuts_one_clients_failing_storm() -> None:
    clock = Clock()
    limit = AccessRateLimit(burst=50, window_s=10.0, clock=clock)
    ok = [_access(f"10.0.0.1:{40000 + i}", f"/v1/cities?n={i}", 200) for i in range(50)]
    assert all(limit.filter(r) for r in ok)  # one client's 2xx budget, the port aside
    storm = [_access("10.0.0.1:39999", "/v1/cities", 401) for _ in range(120)]
    assert sum(limit.filter(r) for r in storm) == 50  # its 4xx have their own budget
    assert limit.filter(_access("10.0.0.2:1", "/v1/cities", 401))  # another client is not cut
    assert limit.filter(_access("10.0.0.1:2", "/healthz", 503))  # nor another status class
    assert not limit.filter(_access("10.0.0.1:3", "/v1/cities", 404))  # 404 is the same 4xx class
    clock.now += 10.0
    nxt = _access("10.0.0.1:4", "/v1/cities?token=***", 401)
    assert limit.filter(nxt)
    line = AccessFormatter('%(client_addr)s - "%(request_line)s" %(status_code)s', use_colors=False).format(
        nxt
    )
    request = '10.0.0.1:4 - "GET /v1/cities?token=*** HTTP/1.1" 401 Unauthorized'
    assert line == request + " [71 similar requests suppressed]"


def test_default_access_budget_is_above_a_platforms_traffic() -> None:
    """An epoch every second per city for ten cities, a dashboard polling every second and a metrics
    scrape every second, all from one address for 10 s: every line kept."""
    clock = Clock()
    limit = AccessRateLimit(clock=clock)
    kept = 0
    for second in range(10):
        clock.now = float(second)
        for city in range(10):
            kept += limit.filter(_access("10.0.0.9:1", f"/v1/cities/c{city}/epochs", 200))
        kept += limit.filter(_access("10.0.0.9:2", "/v1/cities/c0/coverage", 200))
        kept += limit.filter(_access("10.0.0.9:3", "/metrics", 200))
    assert kept == 120


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
