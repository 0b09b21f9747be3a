"""A frozen store must not starve the API. Sixty readers hit a store that answers nothing; only
``store_concurrency`` of them may wait on it, the rest get a 503 while it is still frozen, and liveness and
the routes that need no store (/healthz, a city's description) answer meanwhile instead of waiting behind the
readers for as long as the store stays frozen."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import httpx

from app.adapters import MemoryStore
from app.adapters.city_registry import CityRegistry
from app.bootstrap import create_app
from app.entrypoints.serve import serve_app_in_thread
from app.ports import CityState
from services.model import IntervalKey, TaxiId
from tests.api.conftest import CITY, READ, auth, settings
from tests.api.fakes import FakeDecide

READERS = 60
SLOTS = 4


class FrozenStore(MemoryStore):
    """A store whose reads block while ``frozen`` is set, as calls on a stopped Redis do."""

    def __init__(self) -> None:
        super().__init__()
        self.thawed = threading.Event()
        self.waiting = 0
        self._count = threading.Lock()

    def _wait(self) -> None:
        with self._count:
            self.waiting += 1
        self.thawed.wait(timeout=120)

    def interval_counts(self, city: str, interval: IntervalKey) -> dict[int, int]:
        self._wait()
        return super().interval_counts(city, interval)

    def load_state(
        self,
        city: str,
        intervals: Sequence[IntervalKey],
        taxi_ids: Sequence[TaxiId],
        *,
        visits_from: IntervalKey | None = None,
    ) -> CityState:
        self._wait()
        return super().load_state(city, intervals, taxi_ids, visits_from=visits_from)


def _until(what: str, ok: Callable[[], bool], timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not ok():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout_s:.0f} s: {what}")
        time.sleep(0.02)


def test_frozen_store_yields_fast_503s_and_liveness_answers(registry: CityRegistry) -> None:
    store = FrozenStore()
    conf = settings(store_concurrency=SLOTS, store_queue_s=0.05)
    app = create_app(conf, registry=registry, store=store, decide=FakeDecide())
    results: list[httpx.Response] = []
    lock = threading.Lock()
    with serve_app_in_thread(app, conf) as url:

        def read() -> None:
            with httpx.Client(base_url=url, timeout=120) as c:
                r = c.get(
                    f"/v1/cities/{CITY}/coverage", params={"interval": "2026-11-23T08:00"}, headers=auth(READ)
                )
            with lock:
                results.append(r)

        threads = [threading.Thread(target=read) for _ in range(READERS)]
        for t in threads:
            t.start()
        try:
            # while the store stays frozen: all but SLOTS readers are answered, with a 503
            _until(
                "the readers beyond the store's slots are answered", lambda: len(results) >= READERS - SLOTS
            )
            assert store.waiting == SLOTS and not store.thawed.is_set()
            with httpx.Client(base_url=url, timeout=30) as c:
                assert c.get("/healthz").status_code == 200
                assert c.get(f"/v1/cities/{CITY}", headers=auth(READ)).status_code == 200
                assert c.get("/metrics").status_code == 200
                r = c.get("/readyz")  # needs the store: no slot free, so a 503 and not a wait
                assert r.status_code == 503 and r.json()["detail"] == "store unreachable"
            with lock:
                early = list(results)
            assert {r.status_code for r in early} == {503}
            assert {r.json()["error"] for r in early} == {"store_unavailable"}
            assert {r.json()["detail"] for r in early} == {"store unreachable"}
        finally:
            store.thawed.set()
            for t in threads:
                t.join(timeout=60)
    assert len(results) == READERS
    assert sorted(r.status_code for r in results) == [200] * SLOTS + [503] * (READERS - SLOTS)
