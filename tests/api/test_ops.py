"""Health, readiness, metrics, and a store that cannot be reached (503, never 500)."""

from __future__ import annotations

import gc
import socket
import threading
from pathlib import Path
from typing import Any

import pytest

from app.adapters import RedisStore
from app.adapters.city_registry import CityRegistry
from app.api.warmup import GC_THRESHOLD
from app.bootstrap import create_app
from services.city import City
from services.model import Decision
from tests.api import payloads
from tests.api.conftest import CITY, MakeClient, auth, settings
from tests.api.fakes import FakeDecide


def test_healthz_and_readyz(make_client: MakeClient) -> None:
    client = make_client()
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json() == {"status": "ready", "store": "memory", "cities": [CITY]}


def _join_warm_up() -> None:
    for thread in threading.enumerate():
        if thread.name == "warm-cities":
            thread.join(timeout=60.0)
            assert not thread.is_alive()


def test_the_run_commands_app_tunes_the_collector_once_its_cities_are_warm(registry: CityRegistry) -> None:
    from fastapi.testclient import TestClient

    before, frozen = gc.get_threshold(), gc.get_freeze_count()
    assert before != GC_THRESHOLD
    try:
        plain = create_app(settings(), registry=registry, decide=FakeDecide())
        with TestClient(plain) as client:
            _join_warm_up()
            assert client.get("/readyz").status_code == 200
            assert gc.get_threshold() == before and gc.get_freeze_count() == frozen  # tests' apps leave it be
        collector_on: list[bool] = []
        fake = FakeDecide()

        def decide(*args: Any) -> Decision:
            collector_on.append(gc.isenabled())
            return fake(*args)

        tuned = create_app(settings(), registry=registry, decide=decide, tune_gc=True)
        with TestClient(tuned) as client:
            assert gc.get_threshold() == GC_THRESHOLD
            _join_warm_up()
            assert gc.get_freeze_count() > frozen  # start-up's objects are out of the collector's reach
            r = client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch(), headers=auth())
            assert r.status_code == 200, r.text
            # off while the epoch was solved, on again once its exchange was over
            assert collector_on == [False] and gc.isenabled()
    finally:
        gc.set_threshold(*before)
        gc.unfreeze()


class _HeldCities:
    """A catalog whose cities load only once ``release`` is set (a warm-up that takes its time)."""

    def __init__(self, inner: CityRegistry) -> None:
        self.inner = inner
        self.release = threading.Event()

    def names(self) -> list[str]:
        return self.inner.names()

    def get(self, name: str) -> City:
        if threading.current_thread().name == "warm-cities":
            assert self.release.wait(timeout=60.0)
        return self.inner.get(name)


def test_readyz_is_503_until_the_warm_up_has_finished(registry: CityRegistry) -> None:
    from fastapi.testclient import TestClient

    held = _HeldCities(registry)
    app = create_app(settings(), registry=held, decide=FakeDecide())
    with TestClient(app) as client:
        client.get("/healthz")  # the warm-up thread is running (and held) by now
        r = client.get("/readyz")
        assert r.status_code == 503, r.text
        assert r.json()["error"] == "unavailable" and "warming up" in r.json()["detail"]
        assert client.get("/healthz").json() == {"status": "ok"}  # alive all along
        held.release.set()
        _join_warm_up()
        assert client.get("/readyz").json() == {"status": "ready", "store": "memory", "cities": [CITY]}


def test_readyz_without_cities_is_503(tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    empty = CityRegistry(bundled_dir=tmp_path / "a", user_dir=tmp_path / "b")
    r = TestClient(create_app(settings(), registry=empty, decide=FakeDecide())).get("/readyz")
    assert r.status_code == 503 and r.json()["error"] == "unavailable"


@pytest.fixture
def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])  # closed again on return: nothing listens there


def test_unreachable_store_is_503(make_client: MakeClient, closed_port: int) -> None:
    store = RedisStore(f"redis://127.0.0.1:{closed_port}/0", socket_timeout_s=0.5)
    client = make_client(store=store)
    for r in (
        client.get("/readyz"),
        client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch(), headers=auth()),
        client.post(f"/v1/cities/{CITY}/tasks", json=payloads.tasks(), headers=auth()),
        client.get(f"/v1/cities/{CITY}/tasks", headers=auth()),
        client.get(f"/v1/cities/{CITY}/coverage", headers=auth()),
    ):
        assert r.status_code == 503, r.text
        assert r.json()["error"] == "store_unavailable"
    # what needs no store still works
    assert client.get("/healthz").status_code == 200
    assert client.get(f"/v1/cities/{CITY}", headers=auth()).status_code == 200
    text = client.get("/metrics").text
    assert 'sd_errors_total{kind="store_unavailable"} 5.0' in text
    assert 'sd_epochs_total{outcome="store_unavailable"} 1.0' in text
    store.close()


def test_metrics(make_client: MakeClient) -> None:
    client = make_client()
    client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch(), headers=auth())
    client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch(), headers=auth())
    client.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch("e0", -5), headers=auth())
    client.post(f"/v1/cities/{CITY}/epochs", json={"bad": 1}, headers=auth())
    r = client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    text = r.text
    for line in (
        'sd_epochs_total{outcome="committed"} 1.0',
        'sd_epochs_total{outcome="replayed"} 1.0',
        'sd_epochs_total{outcome="stale_epoch"} 1.0',
        'sd_rider_matches_total{step="1"} 1.0',
        'sd_rider_matches_total{step="2"} 1.0',
        "sd_task_assignments_total 0.0",
        'sd_errors_total{kind="stale_epoch"} 1.0',
        'sd_errors_total{kind="validation_error"} 1.0',
        "sd_epoch_latency_seconds_count 3.0",
    ):
        assert line in text, line


def test_metrics_are_per_app(make_client: MakeClient) -> None:
    a, b = make_client(), make_client()
    a.post(f"/v1/cities/{CITY}/epochs", json=payloads.epoch(), headers=auth())
    assert 'sd_epochs_total{outcome="committed"} 0.0' in b.get("/metrics").text
