"""The fault suite: one seeded replay (Chengdu, a small fleet) under faults must end exactly like the same
replay in-process: every rider's fate, every task, every assignment and every grid count equal.

* Redis (with AOF) killed with SIGKILL at moments spread over the replay, and started again on the same
  port and directory: the service answers 503 meanwhile, the client retries the same epoch id;
* the API process killed with SIGKILL mid-replay, and started again: the client retries through the gap;
* two API replicas on one Redis, every epoch posted to both at the same moment (one commits, the other
  answers the stored response).

Real redis-server and ``python -m app run`` processes, all on 127.0.0.1; each test stops what it starts.
"""

from __future__ import annotations

import subprocess
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.adapters.redis_store import RedisStore
from app.entrypoints.replay_client import HttpDispatcher
from app.entrypoints.serve import serve_in_thread
from services.city import City
from services.citydata import load_city
from services.model import Snapshot
from services.sim.engine import RunTrace
from services.sim.local import LocalDispatcher, Outcome
from tests.conftest import delete_prefix
from tests.e2e.service import ROOT, start_service, stop, wait_ready
from tests.e2e.test_replay import _compare, _run
from tests.faults import AofRedis, free_port, sigkill

TOKEN = "fault-token-00000001"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
RETRIES = 14  # back-off 0.2, 0.4, ... capped at 5 s: about 50 s of retrying, more than a restart takes


@pytest.fixture(scope="module")
def city() -> City:
    return load_city(ROOT / "app" / "data" / "cities" / "chengdu")


@pytest.fixture(scope="module")
def local(city: City) -> RunTrace:
    return _run(city, LocalDispatcher(city), "")


class Faulty(HttpDispatcher):
    """An ``HttpDispatcher`` that calls ``before(i)`` before posting its ``i``-th epoch."""

    def __init__(self, client: httpx.Client, city: City, before: Callable[[int], None]) -> None:
        super().__init__(client, "chengdu", city, retries=RETRIES)
        self.before = before
        self.posted = 0

    def epoch(self, snapshot: Snapshot) -> Outcome:
        self.before(self.posted)
        self.posted += 1
        return super().epoch(snapshot)


def _later(delay_s: float, fn: Callable[[], None]) -> None:
    def run() -> None:
        time.sleep(delay_s)
        fn()

    threading.Thread(target=run, daemon=True).start()


# -------------------------------------------------------------------------------- Redis killed (AOF)


def test_redis_killed_mid_replay_counts_like_an_unfaulted_run(
    city: City, local: RunTrace, tmp_path: Path
) -> None:
    server = AofRedis(tmp_path)
    server.start()
    store = RedisStore(server.url, prefix="fault", socket_timeout_s=1.0)
    restarted = threading.Event()

    def bounce() -> None:
        server.kill()
        time.sleep(0.5)
        server.start()
        restarted.set()

    def before(i: int) -> None:
        if i in (15, 40, 70):  # the kill lands while this epoch is being solved or committed
            restarted.clear()
            _later(0.005 * (i % 7), bounce)

    try:
        with (
            serve_in_thread(store) as (url, token),
            httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=120) as client,
        ):
            dispatcher = Faulty(client, city, before)
            remote = _run(city, dispatcher, "k-")
            assert restarted.wait(60)
    finally:
        store.close()
        server.stop()
    assert server.kills == 3 and dispatcher.posted > 70 and dispatcher.retried >= 1
    _compare(city, local, remote, "k-")


# -------------------------------------------------------------------------------- API process killed


class ApiProcess:
    """``python -m app run`` on a fixed port, on Redis under ``prefix``; SIGKILL and start again."""

    def __init__(self, redis_url: str, prefix: str) -> None:
        self.redis_url, self.prefix = redis_url, prefix
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen[bytes] | None = None
        self.kills = 0

    def start(self) -> None:
        self.proc, _ = start_service(
            self.redis_url, self.prefix, {TOKEN: ["read", "dispatch"]}, port=self.port
        )

    def ready(self) -> None:
        assert self.proc is not None
        wait_ready(self.url, self.proc)

    def kill(self) -> None:
        self.kills += sigkill(self.proc)

    def stop(self) -> None:
        if self.proc is not None:
            stop(self.proc)


@pytest.fixture
def fault_prefix(redis_url: str) -> Iterator[str]:
    prefix = f"fault{uuid.uuid4().hex[:10]}"
    yield prefix
    delete_prefix(redis_url, prefix)


def test_api_killed_mid_replay_counts_like_an_unfaulted_run(
    city: City, local: RunTrace, redis_url: str, fault_prefix: str
) -> None:
    api = ApiProcess(redis_url, fault_prefix)
    api.start()

    def bounce() -> None:
        api.kill()
        api.start()

    def before(i: int) -> None:
        if i in (20, 60):
            _later(0.01 * (i % 5), bounce)

    try:
        api.ready()
        with httpx.Client(base_url=api.url, headers=AUTH, timeout=120) as client:
            dispatcher = Faulty(client, city, before)
            remote = _run(city, dispatcher, "a-")
    finally:
        api.stop()
    assert api.kills == 2 and dispatcher.retried >= 2
    _compare(city, local, remote, "a-")


# -------------------------------------------------------------------------------- two replicas


class BothReplicas(HttpDispatcher):
    """Posts every request to both replicas at the same moment; an epoch's two answers must be the same
    bytes, one of them the stored answer (task registrations race too: one creates, one finds them)."""

    def __init__(self, a: httpx.Client, b: httpx.Client, city: City) -> None:
        super().__init__(a, "chengdu", city, retries=RETRIES)
        self.b = HttpDispatcher(b, "chengdu", city, retries=RETRIES)
        self.pool = ThreadPoolExecutor(2)
        self.replays = 0

    def _request(self, method: str, url: str, what: str, **kwargs: Any) -> httpx.Response:
        mine = self.pool.submit(HttpDispatcher._request, self, method, url, what, **kwargs)
        theirs = self.pool.submit(HttpDispatcher._request, self.b, method, url, what, **kwargs)
        r, s = mine.result(), theirs.result()
        if method == "POST" and url.endswith("/epochs"):
            assert r.content == s.content, what
            replayed = [x.headers.get("Idempotent-Replayed") == "true" for x in (r, s)]
            assert replayed.count(True) == 1, (what, replayed)  # one commit, one stored answer
            self.replays += 1
        return r


def test_two_replicas_with_concurrent_duplicates_count_like_one(
    city: City, local: RunTrace, redis_url: str, fault_prefix: str
) -> None:
    replicas = [ApiProcess(redis_url, fault_prefix) for _ in range(2)]
    for api in replicas:
        api.start()
    try:
        for api in replicas:
            api.ready()
        with (
            httpx.Client(base_url=replicas[0].url, headers=AUTH, timeout=120) as a,
            httpx.Client(base_url=replicas[1].url, headers=AUTH, timeout=120) as b,
        ):
            dispatcher = BothReplicas(a, b, city)
            remote = _run(city, dispatcher, "d-")
            dispatcher.pool.shutdown()
    finally:
        for api in replicas:
            api.stop()
    assert dispatcher.replays > 50
    _compare(city, local, remote, "d-")
