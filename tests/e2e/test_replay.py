"""The replay client drives a running service over HTTP; in-process and HTTP runs must agree exactly.

One seeded horizon (Chengdu, a small fleet, random demand) is simulated three ways: with the core in-process
(``LocalDispatcher``), against a real uvicorn service on the in-memory store, and against one on a real Redis
through a transport that loses some epoch responses after the service committed them (the client retries the
same epoch id). All three must produce the same riders' fates, the same tasks and the same counts.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import httpx
import numpy as np
import pytest

from app.adapters.redis_store import RedisStore
from app.entrypoints.replay_client import HttpDispatcher
from app.entrypoints.serve import serve_in_thread
from services.city import City
from services.citydata import load_city
from services.sim.demand import DemandSet, Request
from services.sim.engine import RunTrace, SimConfig, poi_tasks, simulate
from services.sim.kpi import run_kpis
from services.sim.local import LocalDispatcher

DATE = "2016-11-02"


@pytest.fixture(scope="module")
def city() -> City:
    return load_city("app/data/cities/chengdu")


def _demand(city: City, n: int, seed: int) -> DemandSet:
    rng = np.random.default_rng(seed)
    start = city.horizon.start_s(DATE)
    times = np.sort(np.floor(start + rng.random(n) * city.horizon.length_s))
    nodes = rng.integers(city.network.n_nodes, size=(n, 2))
    reqs = tuple(
        Request(f"r{i:04d}", float(t), int(o), int(d))
        for i, (t, (o, d)) in enumerate(zip(times, nodes, strict=True))
    )
    return DemandSet(city.name, DATE, reqs, "test-uniform", seed=seed)


def _run(city: City, dispatcher: object, prefix: str) -> RunTrace:
    demand = _demand(city, 160, seed=11)
    start = city.horizon.start_s(DATE)
    tasks = poi_tasks(
        np.arange(0, city.network.n_nodes, 97),
        24,
        start,
        city.horizon.length_s,
        np.random.default_rng(5),
        prefix,
    )
    cfg = SimConfig(n_instrumented=8, n_ordinary=6, n_tasks=24, seed=3, id_prefix=prefix)
    return simulate(city, demand, tasks, cfg, dispatcher)  # type: ignore[arg-type]


def _fates(trace: RunTrace, prefix: str) -> list[tuple[object, ...]]:
    return [
        (
            r.id.removeprefix(prefix),
            r.matched_at_s,
            r.step,
            (r.taxi_id or "").removeprefix(prefix),
            None if r.pickup_s is None else round(r.pickup_s, 6),
            r.left_at_s,
        )
        for r in trace.riders
    ]


def _tasks(trace: RunTrace, prefix: str) -> list[tuple[object, ...]]:
    return [
        (
            t.id.removeprefix(prefix),
            t.node,
            t.status,
            None if t.completed_at_s is None else round(t.completed_at_s, 3),
            t.mode,
            (t.taxi_id or "").removeprefix(prefix),
        )
        for t in trace.tasks
    ]


@pytest.fixture(scope="module")
def local(city: City) -> RunTrace:
    return _run(city, LocalDispatcher(city), "")


class _LosesResponses(httpx.BaseTransport):
    """Forwards every request; for every ``every``-th epoch post, drops the response after the service has
    handled it (as a network failure after the commit would) and raises a read error."""

    def __init__(self, every: int) -> None:
        self.inner = httpx.HTTPTransport()
        self.every = every
        self.posts = 0
        self.dropped = 0

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        response = self.inner.handle_request(request)
        if request.method == "POST" and request.url.path.endswith("/epochs"):
            self.posts += 1
            if self.posts % self.every == 0:
                response.read()
                response.close()
                self.dropped += 1
                raise httpx.ReadError("connection lost after the service answered", request=request)
        return response

    def close(self) -> None:
        self.inner.close()


def _compare(city: City, local: RunTrace, remote: RunTrace, prefix: str) -> None:
    assert _fates(remote, prefix) == _fates(local, "")
    assert _tasks(remote, prefix) == _tasks(local, "")
    assert [
        (round(t, 6), a.taxi_id.removeprefix(prefix), a.task_id.removeprefix(prefix), a.path)
        for t, a in remote.assignments
    ] == [(round(t, 6), a.taxi_id, a.task_id, a.path) for t, a in local.assignments]
    for k in local.counts:
        np.testing.assert_array_equal(remote.counts[k], local.counts[k])
    a, b = run_kpis(city, local).scalars(), run_kpis(city, remote).scalars()
    a.pop("solve_ms_median")
    b.pop("solve_ms_median")
    assert a.keys() == b.keys()
    for key in a:
        assert b[key] == pytest.approx(a[key], rel=1e-9, abs=1e-6, nan_ok=True), key


def test_local_run_is_not_trivial(city: City, local: RunTrace) -> None:
    k = run_kpis(city, local)
    assert k.n_step1 > 0 and k.n_step2 > 0 and k.n_active > 0
    # 14 taxis for 160 requests: patience runs out for some (the replays must agree on who)
    assert 0 < k.riders_lost <= k.riders_unserved < k.n_requests
    assert sum(int(c.sum()) for c in local.counts.values()) > 0


def test_replay_over_http_memory_store_matches_in_process(city: City, local: RunTrace) -> None:
    with (
        serve_in_thread() as (url, token),
        httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=120) as client,
    ):
        remote = _run(city, HttpDispatcher(client, "chengdu", city), "m-")
    _compare(city, local, remote, "m-")


@pytest.fixture
def redis_service(redis_store: RedisStore) -> Iterator[tuple[str, str]]:
    with serve_in_thread(redis_store) as served:
        yield served


def test_replay_over_http_redis_with_lost_responses_matches_in_process(
    city: City, local: RunTrace, redis_service: tuple[str, str]
) -> None:
    url, token = redis_service
    transport = _LosesResponses(every=7)
    with httpx.Client(
        base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=120, transport=transport
    ) as client:
        dispatcher = HttpDispatcher(client, "chengdu", city)
        remote = _run(city, dispatcher, "r-")
    assert transport.dropped >= 5 and dispatcher.retried == transport.dropped
    _compare(city, local, remote, "r-")


def test_replay_over_http_redis_cluster_matches_in_process(
    city: City, local: RunTrace, make_cluster_store: Callable[[], RedisStore]
) -> None:
    """The service on a real 3-master Redis Cluster (``SD_REDIS_MODE=cluster``) decides and counts like the
    core in-process."""
    with (
        serve_in_thread(make_cluster_store()) as (url, token),
        httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=120) as client,
    ):
        remote = _run(city, HttpDispatcher(client, "chengdu", city), "c-")
    _compare(city, local, remote, "c-")
