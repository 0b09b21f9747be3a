"""ASGI middleware that holds the foreground for an epoch post's whole exchange: from the moment its
headers arrive, through receiving its body, parsing, solving and committing, to its response handed to the
server. The embedded fleet worker's runs stay stopped throughout (``app.runs.executor.Foreground``,
docs/FLEET.md), so none of the request's work on this service's CPU competes with them: a 230 KB body of
2,000 taxis is read and the response written while they would otherwise hold both cores. In the service's
own process the hold also keeps the garbage collector off until the exchange ends
(``app.api.collector``).

Only a post whose bearer token may dispatch is held: the body's arrival is held too, so a client without
that token, sending its body slowly, would otherwise keep the worker stopped for as long as the body's
deadline allows (``SD_BODY_TIMEOUT_S``). The route checks the token again, as every route does."""

from __future__ import annotations

import re
from collections.abc import Callable
from contextlib import AbstractContextManager

from fastapi.security.utils import get_authorization_scheme_param
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

__all__ = ["EpochForeground", "EPOCH_POST", "bearer_token"]

EPOCH_POST = re.compile(r"/v1/cities/[^/]+/epochs")
"""The path of an epoch post (the method is POST)."""


def bearer_token(scope: Scope) -> str | None:
    """The request's bearer token (``Authorization: Bearer <token>``), read as FastAPI's ``HTTPBearer`` reads
    it, or None."""
    scheme, token = get_authorization_scheme_param(Headers(scope=scope).get("authorization"))
    return token if scheme.lower() == "bearer" and token else None


class EpochForeground:
    """Hold ``hold()`` around the whole exchange of every epoch post (``EPOCH_POST``) whose bearer token
    ``dispatches`` says may post it; every other request passes through as it is. ``hold`` is called per
    request, so it reads the service's current foreground."""

    def __init__(
        self,
        app: ASGIApp,
        hold: Callable[[], AbstractContextManager[None]],
        dispatches: Callable[[str], bool],
    ) -> None:
        self.app = app
        self.hold = hold
        self.dispatches = dispatches

    def _held(self, scope: Scope) -> bool:
        if scope["type"] != "http" or scope["method"] != "POST" or not EPOCH_POST.fullmatch(scope["path"]):
            return False
        token = bearer_token(scope)
        return token is not None and self.dispatches(token)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Pass the request on, inside the hold when it is an epoch post that may dispatch."""
        if not self._held(scope):
            await self.app(scope, receive, send)
            return
        with self.hold():
            await self.app(scope, receive, send)
