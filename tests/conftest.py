"""Root fixtures: a real Redis server (and a real 3-master Redis Cluster) for the tests that need one, and
clean per-test key prefixes.

``REDIS_URL`` set: that server is used (it must answer PING) and never flushed; each test works under its
own key prefix, deleted afterwards. Not set: a throwaway ``redis-server`` is started on a free port for the
session. If neither works the tests that need Redis fail with the reason; they are never skipped.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import redis

from app.adapters import MemoryStore, RedisStore
from app.adapters.redis_store import RedisMode

_START_TIMEOUT_S = 15.0


def _answers_ping(url: str) -> str | None:
    """None when the server at ``url`` answers PING, else the reason it does not."""
    client = redis.Redis.from_url(url, socket_timeout=2, socket_connect_timeout=2)
    try:
        client.ping()
        return None
    except redis.RedisError as exc:
        return f"{type(exc).__name__}: {exc}"
    finally:
        client.close()


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start_redis(binary: str, workdir: Path) -> tuple[subprocess.Popen[bytes], str]:
    """Start ``redis-server`` on a free port; retry a few ports in case one is taken meanwhile."""
    reasons: list[str] = []
    for attempt in range(3):
        port = _free_port()
        log = workdir / f"redis-{attempt}.log"
        cmd = [binary, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
               "--dir", str(workdir), "--logfile", str(log)]  # fmt: skip
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        url = f"redis://127.0.0.1:{port}/0"
        deadline = time.monotonic() + _START_TIMEOUT_S
        reason: str | None = "not started"
        while time.monotonic() < deadline and proc.poll() is None:
            reason = _answers_ping(url)
            if reason is None:
                return proc, url
            time.sleep(0.05)
        _stop(proc)
        tail = log.read_text(errors="replace")[-800:] if log.exists() else ""
        err = proc.stderr.read().decode(errors="replace")[-400:] if proc.stderr else ""
        reasons.append(f"port {port}: exit code {proc.returncode}, last error {reason}; {err}{tail}".strip())
    raise RuntimeError("could not start redis-server:\n" + "\n".join(reasons))


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


@pytest.fixture(scope="session")
def redis_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """URL of a Redis server for this session: ``REDIS_URL`` if set, else a throwaway ``redis-server``."""
    url = os.environ.get("REDIS_URL", "").strip()
    if url:
        reason = _answers_ping(url)
        if reason is not None:
            pytest.fail(f"REDIS_URL={url!r} does not answer PING ({reason}); Redis tests are never skipped")
        yield url
        return
    binary = shutil.which("redis-server")
    if binary is None:
        pytest.fail(
            "Redis tests need a Redis server: set REDIS_URL to a running one or put redis-server on PATH "
            "(e.g. apt-get install redis-server); they are never skipped"
        )
    try:
        proc, url = _start_redis(binary, tmp_path_factory.mktemp("redis"))
    except RuntimeError as exc:
        pytest.fail(f"{exc}\nSet REDIS_URL to a running server instead; Redis tests are never skipped")
    try:
        yield url
    finally:
        _stop(proc)


@pytest.fixture
def redis_prefix(redis_url: str) -> Iterator[str]:
    """A key prefix unique to this test; its keys are deleted afterwards (the server is never flushed)."""
    prefix = f"sdtest-{uuid.uuid4().hex[:12]}"
    yield prefix
    delete_prefix(redis_url, prefix)


def delete_prefix(url: str, prefix: str) -> None:
    """Delete every key under ``prefix:``."""
    client = redis.Redis.from_url(url, socket_timeout=5)
    try:
        batch = list(client.scan_iter(match=f"{prefix}:*", count=1000))
        for i in range(0, len(batch), 1000):
            client.delete(*batch[i : i + 1000])
    finally:
        client.close()


@pytest.fixture
def redis_store(redis_url: str, redis_prefix: str) -> Iterator[RedisStore]:
    """A ``RedisStore`` on the test server under a fresh prefix."""
    store = RedisStore(redis_url, prefix=redis_prefix)
    yield store
    store.close()


@pytest.fixture
def memory_store() -> MemoryStore:
    """A fresh ``MemoryStore``."""
    return MemoryStore()


@pytest.fixture
def make_redis_store(redis_url: str) -> Iterator[Callable[[], RedisStore]]:
    """Factory of ``RedisStore``s, each under its own fresh prefix; all closed and cleaned afterwards."""
    yield from _store_factory(redis_url, "standalone")


def _store_factory(url: str, mode: RedisMode) -> Iterator[Callable[[], RedisStore]]:
    made: list[tuple[RedisStore, str]] = []

    def make() -> RedisStore:
        prefix = f"sdtest-{uuid.uuid4().hex[:12]}"
        store = RedisStore(url, prefix=prefix, mode=mode)
        made.append((store, prefix))
        return store

    yield make
    for store, prefix in made:
        store.close()
        (delete_prefix_cluster if mode == "cluster" else delete_prefix)(url, prefix)


def _free_cluster_port() -> int:
    """A free port whose cluster bus port (port + 10000) is free and valid too."""
    for _ in range(200):
        port = _free_port()
        if port + 10000 > 65535:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port + 10000))
            except OSError:
                continue
        return port
    raise RuntimeError("no free port pair (port, port + 10000) for a cluster node")


def _start_cluster(binary: str, workdir: Path) -> tuple[list[subprocess.Popen[bytes]], str]:
    """Three ``redis-server --cluster-enabled yes`` on free loopback ports joined by
    ``redis-cli --cluster create`` (no replicas); the URL names the first node."""
    cli = shutil.which("redis-cli")
    if cli is None:
        raise RuntimeError("redis-cli is not on PATH (it joins the cluster's nodes)")
    procs: list[subprocess.Popen[bytes]] = []
    ports: list[int] = []
    try:
        for i in range(3):
            port = _free_cluster_port()
            node_dir = workdir / f"node{i}"
            node_dir.mkdir()
            cmd = [binary, "--port", str(port), "--bind", "127.0.0.1", "--cluster-enabled", "yes",
                   "--cluster-config-file", "nodes.conf", "--cluster-node-timeout", "2000",
                   "--save", "", "--appendonly", "no", "--dir", str(node_dir),
                   "--logfile", str(node_dir / "redis.log")]  # fmt: skip
            procs.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            ports.append(port)
        for port in ports:
            deadline = time.monotonic() + _START_TIMEOUT_S
            while _answers_ping(f"redis://127.0.0.1:{port}/0") is not None:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"cluster node on port {port} did not start")
                time.sleep(0.05)
        create = [cli, "--cluster", "create", *(f"127.0.0.1:{p}" for p in ports),
                  "--cluster-replicas", "0", "--cluster-yes"]  # fmt: skip
        done = subprocess.run(create, capture_output=True, timeout=60, check=False)
        if done.returncode != 0:
            raise RuntimeError(
                f"redis-cli --cluster create failed: {done.stdout[-500:]!r} {done.stderr[-500:]!r}"
            )
        deadline = time.monotonic() + _START_TIMEOUT_S
        for port in ports:
            client = redis.Redis(host="127.0.0.1", port=port, decode_responses=True)
            try:
                while client.cluster("info").get("cluster_state") != "ok":
                    if time.monotonic() > deadline:
                        raise RuntimeError(f"cluster state not ok on port {port}")
                    time.sleep(0.1)
            finally:
                client.close()
        return procs, f"redis://127.0.0.1:{ports[0]}/0"
    except BaseException:
        for proc in procs:
            _stop(proc)
        raise


@pytest.fixture(scope="session")
def redis_cluster_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """URL of one node of a throwaway 3-master Redis Cluster started for this session (never skipped)."""
    binary = shutil.which("redis-server")
    if binary is None:
        pytest.fail("the Redis Cluster tests need redis-server and redis-cli on PATH; they are never skipped")
    try:
        procs, url = _start_cluster(binary, tmp_path_factory.mktemp("redis-cluster"))
    except (RuntimeError, OSError, subprocess.TimeoutExpired) as exc:
        pytest.fail(f"could not start a Redis Cluster: {exc}")
    try:
        yield url
    finally:
        for proc in procs:
            _stop(proc)


def delete_prefix_cluster(url: str, prefix: str) -> None:
    """Delete every key under ``prefix:`` on every node of a cluster."""
    from redis.cluster import RedisCluster

    client = RedisCluster.from_url(url, socket_timeout=5)
    try:
        for key in list(client.scan_iter(match=f"{prefix}:*", count=1000)):
            client.delete(key)
    finally:
        client.close()


@pytest.fixture
def make_cluster_store(redis_cluster_url: str) -> Iterator[Callable[[], RedisStore]]:
    """Factory of cluster-mode ``RedisStore``s, each under its own fresh prefix; closed and cleaned after."""
    yield from _store_factory(redis_cluster_url, "cluster")


_E2E = Path(__file__).resolve().parent / "e2e"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test that uses the Redis server ``redis`` and every end-to-end test ``slow`` (whole
    simulated days, processes, servers); ``make check`` runs the rest as its quick tests."""
    for item in items:
        names = getattr(item, "fixturenames", ())
        if "redis_url" in names or "redis_cluster_url" in names:
            item.add_marker(pytest.mark.redis)
        if _E2E in Path(str(item.path)).parents:
            item.add_marker(pytest.mark.slow)
