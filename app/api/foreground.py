"""ASGI middleware that holds the foreground for an epoch post's whole exchange: from the moment its
headers arrive, through receiving its body, parsing, solving and committing, to its response handed to the
server. The embedded fleet worker's runs stay stopped throughout (``app.runs.executor.Foreground``,
docs/FLEET.md), so none of the request's work on this service's CPU competes with them: a 230 KB body of
2,000 taxis is read and the response written while they would otherwise hold both cores."""

from __future__ import annotations

import re
from collections.abc import Callable
from contextlib import AbstractContextManager

from starlette.types import ASGIApp, Receive, Scope, Send

__all__ = ["EpochForeground", "EPOCH_POST"]

EPOCH_POST = re.compile(r"/v1/cities/[^/]+/epochs")
"""The path of an epoch post (the method is POST)."""


class EpochForeground:
    """Hold ``hold()`` around the whole exchange of every epoch post (``EPOCH_POST``); other requests pass
    through as they are. ``hold`` is called per request, so it reads the service's current foreground."""

    def __init__(self, app: ASGIApp, hold: Callable[[], AbstractContextManager[None]]) -> None:
        self.app = app
        self.hold = hold

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Pass the request on, inside the hold when it is an epoch post."""
        if scope["type"] != "http" or scope["method"] != "POST" or not EPOCH_POST.fullmatch(scope["path"]):
            await self.app(scope, receive, send)
            return
        with self.hold():
            await self.app(scope, receive, send)
