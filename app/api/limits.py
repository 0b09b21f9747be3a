"""ASGI middleware that refuses bodies above ``max_body_bytes`` (by Content-Length and by actual bytes) and
bodies that take longer than ``timeout_s`` to arrive (408, connection closed: a slow client cannot hold a
connection and a worker forever)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.errors import BadRequest, PayloadTooLarge, RequestTimeout, ServiceError

__all__ = ["BodyLimit"]


class BodyLimit:
    """Buffer a request body up to ``max_bytes``; answer 413 above, without calling the app."""

    def __init__(
        self,
        app: ASGIApp,
        max_bytes: int,
        render: Callable[[ServiceError], ASGIApp],
        timeout_s: float | None = None,
    ) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.render = render
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Check the declared and the actual size, then replay the buffered body to the app."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = None
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await self.render(BadRequest("invalid Content-Length header"))(scope, receive, send)
                    return
        too_large = PayloadTooLarge(f"request body exceeds {self.max_bytes} bytes")
        if declared is not None and declared > self.max_bytes:
            await self.render(too_large)(scope, receive, send)
            return
        chunks: list[bytes] = []
        size = 0
        loop = asyncio.get_running_loop()
        deadline = None if self.timeout_s is None else loop.time() + self.timeout_s
        while True:
            try:
                async with asyncio.timeout_at(deadline):
                    message = await receive()
            except TimeoutError:
                late = RequestTimeout(f"the request body did not arrive within {self.timeout_s} s")
                await self.render(late)(scope, receive, send)
                return
            if message["type"] != "http.request":
                # client went away: hand the app the disconnect
                await self.app(scope, _replay([message], receive), send)
                return
            body = message.get("body", b"")
            size += len(body)
            if size > self.max_bytes:
                await self.render(too_large)(scope, receive, send)
                return
            chunks.append(body)
            if not message.get("more_body", False):
                break
        whole: Message = {"type": "http.request", "body": b"".join(chunks), "more_body": False}
        await self.app(scope, _replay([whole], receive), send)


def _replay(messages: list[Message], receive: Receive) -> Receive:
    pending = list(messages)

    async def replayed() -> Message:
        if pending:
            return pending.pop(0)
        return await receive()

    return replayed
