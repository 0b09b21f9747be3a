"""A Dask cluster on this machine for development, the tests and the benchmark: a scheduler and N workers,
each a separate process (``dask scheduler`` / ``dask worker --no-nanny``) on free 127.0.0.1 ports.

    with LocalCluster(2, directory) as cluster:
        runner = Runner(cache, DaskExecutor(cluster.address))

Production clusters are started by their own deployment (docker-compose.yml, deploy/SCALING.md).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

from distributed import Client

__all__ = ["LocalCluster", "free_port"]

R = TypeVar("R")

ROOT = Path(__file__).resolve().parents[2]  # the repository: workers import app.* (and tests.*) from it


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen[bytes], timeout_s: float = 10.0) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=timeout_s)


class LocalCluster:
    """``workers`` Dask worker processes of ``threads`` threads each and their scheduler; logs and the
    workers' local directories under ``directory``. ``start`` waits until every worker has joined."""

    def __init__(
        self, workers: int, directory: Path, *, threads: int = 1, start_timeout_s: float = 60.0
    ) -> None:
        if workers < 0 or threads < 1:
            raise ValueError(f"need workers >= 0 and threads >= 1, got {workers} and {threads}")
        self.n_workers = workers
        self.threads = threads
        self.directory = directory
        self.start_timeout_s = start_timeout_s
        self.port = 0
        self.dashboard_port = 0
        self.scheduler: subprocess.Popen[bytes] | None = None
        self.workers: dict[str, subprocess.Popen[bytes]] = {}  # name -> process
        self._names = 0

    @property
    def address(self) -> str:
        """The scheduler's address (``tcp://127.0.0.1:PORT``)."""
        return f"tcp://127.0.0.1:{self.port}"

    @property
    def dashboard(self) -> str:
        """The scheduler's dashboard (and its Prometheus metrics at ``/metrics``)."""
        return f"http://127.0.0.1:{self.dashboard_port}"

    def _spawn(self, args: list[str], log_name: str) -> subprocess.Popen[bytes]:
        self.directory.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
        with (self.directory / f"{log_name}.log").open("ab") as log:
            return subprocess.Popen(
                [sys.executable, "-m", *args], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT
            )

    def start(self) -> LocalCluster:
        """Start the scheduler and the workers; raise ``RuntimeError`` (with the logs' tails) if they do not
        come up within the start timeout."""
        self.port, self.dashboard_port = free_port(), free_port()
        self.scheduler = self._spawn(
            [
                "distributed.cli.dask_scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                str(self.port),
                "--dashboard-address",
                f"127.0.0.1:{self.dashboard_port}",
            ],
            "scheduler",
        )
        try:
            for _ in range(self.n_workers):
                self.add_worker(wait=False)
            self.wait_for_workers(self.n_workers)
        except BaseException:
            self.stop()
            raise
        return self

    def add_worker(self, *, wait: bool = True) -> subprocess.Popen[bytes]:
        """Start one more worker process (and wait until it has joined, unless ``wait`` is false)."""
        name = f"w{self._names}"
        self._names += 1
        proc = self._spawn(
            [
                "distributed.cli.dask_worker",
                self.address,
                "--name",
                name,
                "--nthreads",
                str(self.threads),
                "--no-nanny",
                "--no-dashboard",
                "--host",
                "127.0.0.1",
                "--death-timeout",
                "60",
                "--local-directory",
                str(self.directory / name),
            ],
            name,
        )
        self.workers[name] = proc
        if wait:
            self.wait_for_workers(sum(p.poll() is None for p in self.workers.values()))
        return proc

    def wait_for_workers(self, n: int) -> None:
        """Block until ``n`` workers are connected to the scheduler."""
        deadline = time.monotonic() + self.start_timeout_s
        while True:
            self._check_alive()
            try:
                with Client(self.address, timeout=5, set_as_default=False) as client:
                    client.wait_for_workers(n, timeout=max(1.0, deadline - time.monotonic()))
                return
            except (OSError, TimeoutError) as exc:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the local Dask cluster did not start: {exc}\n{self.logs()}") from exc
                time.sleep(0.2)

    def run(self, fn: Callable[..., R], *args: Any) -> dict[str, R]:
        """``fn(*args)`` on every worker process now (``fn`` importable there); results by worker address."""
        with Client(self.address, timeout=self.start_timeout_s, set_as_default=False) as client:
            return dict(client.run(fn, *args))

    def _check_alive(self) -> None:
        if self.scheduler is not None and self.scheduler.poll() is not None:
            raise RuntimeError(f"the Dask scheduler exited ({self.scheduler.returncode})\n{self.logs()}")

    def worker_pids(self) -> dict[int, str]:
        """Running worker processes: pid -> name."""
        return {p.pid: name for name, p in self.workers.items() if p.poll() is None}

    def kill_worker(self, pid: int) -> None:
        """SIGKILL one of this cluster's worker processes (no other process: it must be one we started)."""
        name = self.worker_pids().get(pid)
        if name is None:
            raise ValueError(f"pid {pid} is not a running worker of this cluster")
        self.workers[name].kill()
        self.workers[name].wait(timeout=10)

    def kill_scheduler(self) -> None:
        """SIGKILL the scheduler (the cluster is lost; the workers exit after their death timeout)."""
        if self.scheduler is not None:
            self.scheduler.kill()
            self.scheduler.wait(timeout=10)

    def logs(self, tail: int = 1500) -> str:
        """The last characters of every process's log."""
        parts = []
        for path in sorted(self.directory.glob("*.log")):
            parts.append(f"--- {path.name}\n{path.read_text(errors='replace')[-tail:]}")
        return "\n".join(parts)

    def stop(self) -> None:
        """Stop the workers, then the scheduler."""
        for proc in self.workers.values():
            _stop(proc)
        if self.scheduler is not None:
            _stop(self.scheduler)

    def __enter__(self) -> LocalCluster:
        return self.start()

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
