"""The epoch post's foreground hold (``app.api.foreground.EpochForeground``) covers its whole exchange:
the body's arrival, the app's work and the response handed to the server; no other request holds it, nor
an epoch post whose token may not dispatch."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
from typing import Any

import pytest
from starlette.types import Message, Receive, Scope, Send

from app.api.foreground import EpochForeground


class _Depth:
    """A foreground that counts how deep it is held."""

    def __init__(self) -> None:
        self.depth = 0

    @contextlib.contextmanager
    def hold(self) -> Iterator[None]:
        self.depth += 1
        try:
            yield
        finally:
            self.depth -= 1


DISPATCH = b"Bearer dispatch-token"


def _exchange(
    fg: _Depth, method: str, path: str, fail: bool = False, authorization: bytes | None = DISPATCH
) -> list[tuple[str, int]]:
    """One request through the middleware to an app that reads the body and answers: the hold's depth as
    the body is received and as each response message is sent."""
    seen: list[tuple[str, int]] = []

    async def app(scope: Scope, receive: Receive, send: Send) -> None:
        await receive()
        if fail:
            raise RuntimeError("the app failed")
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"{}", "more_body": False})

    async def receive() -> Message:
        seen.append(("receive", fg.depth))
        return {"type": "http.request", "body": b"{}", "more_body": False}

    async def send(message: Message) -> None:
        seen.append((message["type"], fg.depth))

    headers = [] if authorization is None else [(b"authorization", authorization)]
    scope: dict[str, Any] = {"type": "http", "method": method, "path": path, "headers": headers}
    asyncio.run(EpochForeground(app, fg.hold, lambda token: token == "dispatch-token")(scope, receive, send))
    return seen


@pytest.mark.parametrize("authorization", [DISPATCH, b"bearer  dispatch-token ", b"BEARER dispatch-token"])
def test_an_epoch_post_holds_the_foreground_from_its_body_to_its_response(authorization: bytes) -> None:
    fg = _Depth()
    seen = _exchange(fg, "POST", "/v1/cities/chengdu/epochs", authorization=authorization)
    assert seen == [("receive", 1), ("http.response.start", 1), ("http.response.body", 1)]
    assert fg.depth == 0


@pytest.mark.parametrize(
    "authorization", [None, b"Bearer read-token", b"Basic dispatch-token", b"Bearer", b"Bearer   "]
)
def test_an_epoch_post_that_may_not_dispatch_holds_nothing(authorization: bytes | None) -> None:
    """A client without a dispatch token cannot keep the worker stopped by sending its body slowly."""
    fg = _Depth()
    assert {
        depth for _, depth in _exchange(fg, "POST", "/v1/cities/chengdu/epochs", authorization=authorization)
    } == {0}


@pytest.mark.parametrize(
    ("method", "path"),
    [
        ("POST", "/v1/cities/chengdu/tasks"),
        ("GET", "/v1/cities/chengdu/epochs"),
        ("GET", "/v1/cities/chengdu/epochs/e1"),
        ("POST", "/v1/cities/chengdu/epochs/e1"),
        ("POST", "/v1/cities/chengdu/fleet/solve"),
    ],
)
def test_no_other_request_holds_it(method: str, path: str) -> None:
    fg = _Depth()
    assert {depth for _, depth in _exchange(fg, method, path)} == {0}


def test_the_hold_is_released_when_the_app_fails() -> None:
    fg = _Depth()
    with pytest.raises(RuntimeError, match="the app failed"):
        _exchange(fg, "POST", "/v1/cities/chengdu/epochs", fail=True)
    assert fg.depth == 0
