"""Fixtures of the API tests: the tiny city's registry, tokens, and clients over each store."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.adapters import MemoryStore, RedisStore
from app.adapters.city_registry import CityRegistry
from app.bootstrap import create_app
from app.ports import Store
from app.settings import Settings
from app.usecases import DecideFn
from services.model import TaxiId
from tests.api.fakes import CITY as CITY
from tests.api.fakes import FakeDecide, build_bundle

ALL = "tok-all-000000001"
READ = "tok-read-00000001"
DISPATCH = "tok-disp-00000001"
TOKENS = {ALL: ["read", "dispatch"], READ: ["read"], DISPATCH: ["dispatch"]}


def auth(token: str = ALL) -> dict[str, str]:
    """Authorization header for ``token``."""
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture(scope="session")
def cities_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory holding the tiny city's bundle."""
    return build_bundle(tmp_path_factory.mktemp("cities"))


@pytest.fixture(scope="session")
def registry(cities_root: Path, tmp_path_factory: pytest.TempPathFactory) -> CityRegistry:
    """A registry serving only the tiny city."""
    return CityRegistry(bundled_dir=tmp_path_factory.mktemp("no-bundled"), user_dir=cities_root)


def settings(**overrides: Any) -> Settings:
    """Test settings: the tokens above and the given overrides."""
    return Settings(**({"tokens": TOKENS} | overrides))


MakeClient = Callable[..., TestClient]


@pytest.fixture
def make_client(registry: CityRegistry) -> Iterator[MakeClient]:
    """Factory of TestClients over ``create_app``; keyword overrides go to Settings."""
    clients: list[TestClient] = []

    def make(
        store: Store | None = None,
        decide: DecideFn | None = None,
        raise_errors: bool = True,
        clock: Callable[[], float] | None = None,
        **overrides: Any,
    ) -> TestClient:
        app = create_app(
            settings(**overrides),
            registry=registry,
            store=store or MemoryStore(),
            decide=decide or FakeDecide(),
            clock=clock,
        )
        client = TestClient(app, raise_server_exceptions=raise_errors)
        clients.append(client)
        return client

    yield make
    for c in clients:
        c.close()


@pytest.fixture(params=["memory", "redis"])
def any_store(request: pytest.FixtureRequest) -> Store:
    """Each store implementation in turn (the Redis one on the test server, under a fresh prefix)."""
    if request.param == "memory":
        return MemoryStore()
    store: RedisStore = request.getfixturevalue("redis_store")
    return store


TAXI_IDS = [TaxiId(f"t{i}") for i in range(10)]


def fingerprint(store: Store, city: str = CITY) -> tuple[Any, ...]:
    """Everything observable about a city in the store, through the port."""
    intervals = store.list_intervals(city)
    state = store.load_state(city, intervals, TAXI_IDS)
    return (
        state.version,
        state.last_epoch_id,
        state.last_epoch_time_s,
        {k: store.interval_counts(city, k) for k in intervals},
        {t: sorted(v) for t, v in state.visited.items()},
        sorted(store.list_tasks(city), key=lambda t: t.id),
    )
