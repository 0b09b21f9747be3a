"""Run the service inside this process on a free loopback port (demo, replay, end-to-end tests)."""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from app.ports import Store
from app.settings import Settings

__all__ = ["serve_in_thread", "serve_app_in_thread"]


@contextmanager
def serve_in_thread(
    store: Store | None = None, timeout_s: float = 60.0, **settings_overrides: Any
) -> Iterator[tuple[str, str]]:
    """Start uvicorn on 127.0.0.1 (free port) in a background thread; yield ``(url, token)``.

    ``store`` defaults to a fresh in-memory store; the token has scopes ``read`` and ``dispatch``; the
    server is ``app.entrypoints.server``'s (header deadline, connection cap), ``settings_overrides`` go to
    ``Settings``.
    """
    from app.adapters.memory_store import MemoryStore
    from app.bootstrap import create_app
    from app.settings import Settings

    token = "sd_" + secrets.token_urlsafe(24)
    base: dict[str, Any] = {"store": "memory", "tokens": {token: ["read", "dispatch"]}, "host": "127.0.0.1"}
    settings = Settings.model_validate(base | {"port": 0} | settings_overrides)
    app = create_app(settings, store=store if store is not None else MemoryStore())
    with serve_app_in_thread(app, settings, timeout_s) as url:
        yield url, token


@contextmanager
def serve_app_in_thread(app: Any, settings: Settings, timeout_s: float = 60.0) -> Iterator[str]:
    """Serve ``app`` with ``app.entrypoints.server``'s uvicorn on a free loopback port in a thread; yield
    its URL."""
    import uvicorn

    from app.entrypoints.server import server_config

    # the process's logging is the caller's (pytest's, the demo's): no dictConfig from a thread
    config = server_config(app, settings, host="127.0.0.1", port=0, log_level="warning", log_config=None)
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="in-process-service", daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout_s
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("the in-process service did not start")
        time.sleep(0.05)
    port = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=15)
