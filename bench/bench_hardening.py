"""The hardening probes, measured against real processes on 127.0.0.1 (writes docs/PERFORMANCE.md, section
"hardening", and docs/perf_hardening.json):

* the amplification body (1 MiB: ~350,000 empty riders) posted to ``python -m app run``: status, time,
  error-body size, the server's peak RSS (VmHWM) before and after, and the slowest ``/healthz`` answered
  while it was handled (polled every 10 ms); then four such bodies at once;
* how long a connection that never finishes its headers is held (the default header deadline);
* ``/healthz``, a city's description and 60 concurrent coverage readers while Redis is stopped (SIGSTOP);
* a seeded schemathesis run of every operation (counts);
* an end-to-end replay on a real 3-master Redis Cluster, compared with the in-process run.

    python -m bench.bench_hardening            # everything (about three minutes)
    python -m bench.bench_hardening --quick    # fewer schemathesis examples
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx

from bench.report import ROOT, stamp, write_section

sys.path.insert(0, str(ROOT))  # the probes reuse the tests' process helpers

TOKEN = "bench-hardening-token-01"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
MiB = 1 << 20


def _kib(path: str, field: str) -> int:
    for line in Path(path).read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


@contextmanager
def service(**env: str) -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    """``python -m app run`` with the bundled cities on a free port, ready when /readyz answers."""
    from tests.e2e.service import start_process, stop, wait_ready

    proc, url = start_process(env, {TOKEN: ["read", "dispatch", "admin"]})
    try:
        wait_ready(url, proc)
        yield url, proc
    finally:
        stop(proc)


_POLL = """
import json, select, sys, time
import httpx
out = []
with httpx.Client(base_url=sys.argv[1], timeout=60) as c:
    while not select.select([sys.stdin], [], [], 0)[0]:
        t = time.perf_counter()
        c.get("/healthz")
        out.append(time.perf_counter() - t)
        time.sleep(0.01)
print(json.dumps(out))
"""


class HealthPoller:
    """Polls /healthz every 10 ms on one connection from a separate process (so that the probe's own
    threads cannot delay it); the latencies once stopped."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.latencies: list[float] = []
        self._proc: subprocess.Popen[str] | None = None

    def __enter__(self) -> HealthPoller:
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _POLL, self.url], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        time.sleep(0.5)  # its interpreter and first request
        return self

    def __exit__(self, *_: object) -> None:
        assert self._proc is not None
        out = self._proc.communicate("stop\n", timeout=120)[0]
        self.latencies = json.loads(out)


def amplification_body() -> bytes:
    head = b'{"epoch_id":"e1","time":"2026-11-23T08:00:00+08:00","riders":['
    tail = b'],"taxis":[]}'
    n = (MiB - len(head) - len(tail)) // 3
    return head + b",".join([b"{}"] * n) + tail


def probe_amplification() -> dict[str, Any]:
    body = amplification_body()
    with service(SD_STORE="memory") as (url, proc):
        status = f"/proc/{proc.pid}/status"
        rss_before = _kib(status, "VmRSS")
        with httpx.Client(base_url=url, timeout=300) as c, HealthPoller(url) as poll:
            time.sleep(0.2)
            t = time.perf_counter()
            r = c.post(
                "/v1/cities/chengdu/epochs", content=body, headers=AUTH | {"Content-Type": "application/json"}
            )
            one_s = time.perf_counter() - t
            time.sleep(0.2)
        single = {
            "body_bytes": len(body),
            "riders": body.count(b"{}"),
            "status": r.status_code,
            "time_s": one_s,
            "error_body_bytes": len(r.content),
            "fields_listed": len(r.json()["fields"]),
            "detail": r.json()["detail"],
            "rss_before_mib": rss_before / 1024,
            "peak_rss_mib": _kib(status, "VmHWM") / 1024,
            "healthz_max_ms": max(poll.latencies) * 1000,
            "healthz_polls": len(poll.latencies),
        }
        times: list[float] = []
        codes: list[int] = []

        def post() -> None:
            with httpx.Client(base_url=url, timeout=300) as c:
                t = time.perf_counter()
                r = c.post("/v1/cities/chengdu/epochs", content=body, headers=AUTH)
                times.append(time.perf_counter() - t)
                codes.append(r.status_code)

        with HealthPoller(url) as poll:
            threads = [threading.Thread(target=post) for _ in range(4)]
            for th in threads:
                th.start()
            for th in threads:
                th.join()
        four = {
            "statuses": sorted(codes),
            "max_time_s": max(times),
            "healthz_max_ms": max(poll.latencies) * 1000,
            "peak_rss_mib": _kib(status, "VmHWM") / 1024,
        }
    return {"single": single, "four_at_once": four}


def probe_stalled_header() -> dict[str, Any]:
    with service(SD_STORE="memory") as (url, _):
        port = int(url.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port)) as s:
            s.settimeout(120)
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
            t = time.perf_counter()
            reply = b""
            while chunk := s.recv(65536):
                reply += chunk
            held = time.perf_counter() - t
    return {"held_s": held, "reply": reply.split(b"\r\n", 1)[0].decode()}


def probe_frozen_redis() -> dict[str, Any]:
    from tests.faults import AofRedis

    with tempfile.TemporaryDirectory() as tmp:
        redis = AofRedis(Path(tmp))
        redis.start()
        try:
            with service(SD_STORE="redis", SD_REDIS_URL=redis.url, SD_REDIS_PREFIX="bench") as (url, _):
                cov = "/v1/cities/chengdu/coverage"
                params = {"interval": "2026-11-23T08:00"}
                with httpx.Client(base_url=url, timeout=60) as c:
                    assert c.get(cov, params=params, headers=AUTH).status_code == 200
                redis.freeze()
                readers: list[tuple[int, float]] = []
                lock = threading.Lock()
                limits = httpx.Limits(max_connections=100, max_keepalive_connections=100)
                shared = httpx.Client(base_url=url, timeout=120, limits=limits)  # made before the clock runs
                start = threading.Barrier(60)

                def read() -> None:
                    start.wait()
                    t = time.perf_counter()
                    r = shared.get(cov, params=params, headers=AUTH)
                    with lock:
                        readers.append((r.status_code, time.perf_counter() - t))

                city_ms: list[float] = []
                with HealthPoller(url) as poll:
                    threads = [threading.Thread(target=read) for _ in range(60)]
                    for th in threads:
                        th.start()
                    with httpx.Client(base_url=url, timeout=60) as c:
                        for _ in range(20):
                            t = time.perf_counter()
                            c.get("/v1/cities/chengdu", headers=AUTH)
                            city_ms.append((time.perf_counter() - t) * 1000)
                            time.sleep(0.05)
                    for th in threads:
                        th.join()
                shared.close()
                redis.thaw()
        finally:
            redis.stop()
    lat = sorted(x for _, x in readers)
    return {
        "healthz_max_ms": max(poll.latencies) * 1000,
        "healthz_p50_ms": statistics.median(poll.latencies) * 1000,
        "city_max_ms": max(city_ms),
        "readers": dict(Counter(code for code, _ in readers)),
        "reader_p50_s": statistics.median(lat),
        "reader_max_s": lat[-1],
    }


def probe_schemathesis(max_examples: int) -> dict[str, Any]:
    import re

    from tests.e2e.test_schemathesis import run_schemathesis

    t = time.perf_counter()
    code, output = run_schemathesis(max_examples)
    summary = output[output.rfind("SUMMARY") :]
    m = re.search(r"(\d+) generated", summary)
    return {
        "max_examples": max_examples,
        "exit_code": code,
        "generated": int(m.group(1)) if m else None,
        "time_s": time.perf_counter() - t,
        "summary": summary.strip()[-1200:],
    }


def probe_cluster() -> dict[str, Any]:
    import numpy as np

    from app.adapters.redis_store import RedisStore
    from app.entrypoints.replay_client import HttpDispatcher
    from app.entrypoints.serve import serve_in_thread
    from services.citydata import load_city
    from services.sim.local import LocalDispatcher
    from tests.conftest import _start_cluster, _stop
    from tests.e2e.test_replay import _run

    city = load_city(ROOT / "app" / "data" / "cities" / "chengdu")
    local = _run(city, LocalDispatcher(city), "")
    with tempfile.TemporaryDirectory() as tmp:
        procs, url = _start_cluster("redis-server", Path(tmp))
        try:
            store = RedisStore(url, prefix="bench", mode="cluster")
            t = time.perf_counter()
            with (
                serve_in_thread(store) as (base, token),
                httpx.Client(base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=120) as c,
            ):
                dispatcher = HttpDispatcher(c, "chengdu", city)
                remote = _run(city, dispatcher, "c-")
            took = time.perf_counter() - t
            store.close()
        finally:
            for p in procs:
                _stop(p)
    equal = all(np.array_equal(remote.counts[k], local.counts[k]) for k in local.counts)
    return {
        "nodes": 3,
        "epochs": len(remote.epochs),
        "time_s": took,
        "riders": len(remote.riders),
        "counts_equal_in_process": equal,
        "fates_equal_in_process": [r.matched_at_s for r in remote.riders]
        == [r.matched_at_s for r in local.riders],
        "cells_counted": int(sum(int(v.sum()) for v in remote.counts.values())),
    }


def write(results: dict[str, Any]) -> None:
    a, b = results["amplification"]["single"], results["amplification"]["four_at_once"]
    h, f, s, c = (
        results["stalled_header"],
        results["frozen_redis"],
        results["schemathesis"],
        results["cluster"],
    )
    lines = [
        "## Hardening probes",
        "",
        stamp("python -m bench.bench_hardening"),
        f"Load average (1 min) {results['load_before']:.1f} before, {results['load_after']:.1f} after.",
        "Each probe runs against `python -m app run` (default settings, bundled cities) on 127.0.0.1.",
        "",
        "| probe | result |",
        "|---|---|",
        f"| amplification body ({a['body_bytes']} B, {a['riders']} empty riders) | {a['status']} in "
        f"{a['time_s'] * 1000:.0f} ms, error body {a['error_body_bytes']} B ({a['fields_listed']} field listed) |",
        f"| ... server RSS | {a['rss_before_mib']:.0f} MiB before, peak (VmHWM) {a['peak_rss_mib']:.0f} MiB |",
        f"| ... slowest /healthz meanwhile | {a['healthz_max_ms']:.1f} ms ({a['healthz_polls']} polls) |",
        f"| four such bodies at once | {b['statuses']}, slowest {b['max_time_s'] * 1000:.0f} ms, slowest /healthz "
        f"{b['healthz_max_ms']:.1f} ms, peak RSS {b['peak_rss_mib']:.0f} MiB |",
        f"| connection that never finishes its headers | held {h['held_s']:.2f} s, then `{h['reply']}` and closed |",
        f"| /healthz with Redis frozen (SIGSTOP), 60 coverage readers | p50 {f['healthz_p50_ms']:.1f} ms, max "
        f"{f['healthz_max_ms']:.1f} ms; GET /v1/cities/chengdu max {f['city_max_ms']:.1f} ms |",
        f"| ... the 60 readers | {f['readers']}, p50 {f['reader_p50_s'] * 1000:.0f} ms, max "
        f"{f['reader_max_s'] * 1000:.0f} ms |",
        f"| schemathesis, every operation, {s['max_examples']} examples per phase | exit {s['exit_code']}, "
        f"{s['generated']} test cases, {s['time_s']:.0f} s (0 server errors when exit is 0) |",
        f"| replay on a 3-master Redis Cluster | {c['epochs']} epochs, {c['riders']} riders in {c['time_s']:.1f} s; counts equal "
        f"in-process: {c['counts_equal_in_process']}, riders' fates equal: {c['fates_equal_in_process']} |",
    ]
    write_section("hardening", "\n".join(lines))
    (ROOT / "docs" / "perf_hardening.json").write_text(json.dumps(results, indent=2, default=str) + "\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 schemathesis examples instead of 25")
    parser.add_argument("--only", default=None, help="run one probe and print it (no report written)")
    args = parser.parse_args()
    results: dict[str, Any] = {"load_before": os.getloadavg()[0]}
    for name, probe in (
        ("amplification", probe_amplification),
        ("stalled_header", probe_stalled_header),
        ("frozen_redis", probe_frozen_redis),
        ("schemathesis", lambda: probe_schemathesis(5 if args.quick else 25)),
        ("cluster", probe_cluster),
    ):
        if args.only is not None and name != args.only:
            continue
        print(f"{name} ...", flush=True)
        results[name] = probe()
        print(json.dumps(results[name], indent=1, default=str)[:1500], flush=True)
    results["load_after"] = os.getloadavg()[0]
    if args.only is None:
        write(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
