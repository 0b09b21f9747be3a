"""Where an epoch post's time goes besides the solve: the API's own stages, run in this process as the route
runs them, on the epoch benchmark's load (``bench.bench_epoch``'s scenarios, seeded).

Per epoch, each stage timed on its own: the body's parse and validation (``app.api.bodies.epoch_post``), the
epoch command (``app.api.inputs.epoch_command``: node ids resolved, the canonical hash), and inside the use
case (``EpochService.submit_epoch``) the state's load, the decision (``services.dispatch.decide``), the
response's rendering and the commit; "other" is the rest of the use case (the demand record, Gamma before and
after, the tasks' expiry, the counts' view). The collector is set as the service sets it (its thresholds,
start-up's objects frozen, off during each epoch's stages: ``app.api.collector``); the new tasks of each
epoch are registered untimed before it, and the platform follows each decision. What this leaves out is the
HTTP exchange itself (the server, the framework's routing and the client): ``bench.bench_epoch`` measures
the whole round trip.

    python -m bench.bench_http_path --scenario city                 # the in-memory store
    python -m bench.bench_http_path --scenario paper --redis-url redis://127.0.0.1:6379/9
    python -m bench.bench_http_path --scenario city --profile       # and the stages' hottest functions
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import os
import pstats
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, cast

import numpy as np
from pydantic import TypeAdapter

from app.adapters.bounded import BoundedStore
from app.adapters.city_registry import CityRegistry
from app.adapters.memory_store import MemoryStore
from app.api.bodies import epoch_post
from app.api.collector import CollectorDeferral
from app.api.inputs import Limits, epoch_command, tasks_of
from app.api.warmup import GC_THRESHOLD
from app.ports import Store
from app.schemas.tasks import TaskIn
from app.settings import Settings
from app.usecases import EpochLimits, TaskService
from app.usecases.epoch_record import render_epoch
from app.usecases.epochs import EpochService
from bench.bench_epoch import SCENARIOS, Epochs, _epoch_body, load_city, task_docs
from services.dispatch import decide, warm_up
from services.model import Decision

_TASKS = TypeAdapter(list[TaskIn])
STAGES = ("parse", "command", "load", "decide", "render", "commit", "other")


class _Clock:
    """Seconds spent in each stage of the epoch being timed."""

    def __init__(self) -> None:
        self.spent: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        began = time.perf_counter()
        try:
            yield
        finally:
            self.spent[name] = self.spent.get(name, 0.0) + time.perf_counter() - began

    def timed(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def run(*args: Any, **kwargs: Any) -> Any:
            with self.stage(name):
                return fn(*args, **kwargs)

        return run


class _TimedStore:
    """The store with its state load and commit timed (every other call passed through)."""

    def __init__(self, inner: Store, clock: _Clock) -> None:
        self._inner = inner
        self.load_state = clock.timed("load", inner.load_state)
        self.commit_epoch = clock.timed("commit", inner.commit_epoch)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


def _store(redis_url: str | None) -> Store:
    if redis_url is None:
        return MemoryStore()
    from app.adapters.redis_store import RedisStore

    return RedisStore(redis_url, prefix=f"benchpath{os.getpid()}")


def _drop(store: Store, redis_url: str | None) -> None:
    """Close the store, deleting this run's keys from Redis."""
    prefix = getattr(store, "prefix", None)
    store.close()
    if redis_url is not None and prefix:
        import redis

        keys = redis.Redis.from_url(redis_url)
        for key in keys.scan_iter(match=f"{prefix}:*", count=1000):
            keys.delete(key)
        keys.close()


def run(scenario: str, epochs: int, redis_url: str | None = None, profile: bool = False) -> dict[str, Any]:
    """The stages' milliseconds per timed epoch (epochs 1..``epochs``) and, with ``profile``, the hottest
    functions of the stages other than the decision."""
    sc = SCENARIOS[scenario]
    registry = CityRegistry.from_settings(Settings())
    served = registry.get(sc.city)
    city = load_city(sc)
    warm_up(served)
    clock = _Clock()
    raw = _store(redis_url)
    store = _TimedStore(BoundedStore(raw, 8, 10.0), clock)
    prof = cProfile.Profile()
    decided: list[Decision] = []

    def decide_timed(*args: Any) -> Decision:
        if profile:
            prof.disable()
        with clock.stage("decide"):
            decided.append(decide(*args))
        if profile:
            prof.enable()
        return decided[-1]

    service = EpochService(
        registry,
        cast(Store, store),
        decide_timed,
        render_epoch=clock.timed("render", render_epoch),
        limits=EpochLimits(),
    )
    tasks = TaskService(registry, cast(Store, store))
    platform = Epochs(sc, city)
    limits = Limits()
    rows: list[dict[str, float]] = []
    gc.set_threshold(*GC_THRESHOLD)
    gc.collect()
    gc.freeze()
    deferral = CollectorDeferral()
    try:
        for e in range(epochs + 1):
            snap, new = platform.next()
            if new:
                tasks.put_tasks(served, tasks_of(served, _TASKS.validate_python(task_docs(city, new))))
            body = ("application/json", _epoch_body(city, snap).encode())
            clock.spent.clear()
            if profile and e > 0:
                prof.enable()
            with deferral.held(), clock.stage("total"):
                with clock.stage("parse"):
                    post = epoch_post(body, limits)
                with clock.stage("command"):
                    command = epoch_command(served, post.body, post.taxis, post.riders)
                service.submit_epoch(served, command)
            prof.disable()
            platform.apply(decided[-1])
            if e > 0:
                spent = {k: v * 1000.0 for k, v in clock.spent.items()}
                inner = sum(spent[k] for k in ("parse", "command", "load", "decide", "render", "commit"))
                spent["other"] = spent["total"] - inner
                rows.append(spent)
    finally:
        gc.unfreeze()
        _drop(raw, redis_url)
    out: dict[str, Any] = {
        "scenario": scenario,
        "store": "redis" if redis_url else "memory",
        "epochs": epochs,
        "median_ms": {k: float(np.median([r[k] for r in rows])) for k in (*STAGES, "total")},
        "besides_decide_ms": float(np.median([r["total"] - r["decide"] for r in rows])),
    }
    if profile:
        text = io.StringIO()
        pstats.Stats(prof, stream=text).sort_stats("tottime").print_stats(25)
        out["profile"] = text.getvalue()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", choices=["paper", "city"], default="city")
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--redis-url", metavar="URL", help="the Redis store at URL (a fresh key prefix) instead")
    ap.add_argument("--profile", action="store_true", help="also print the stages' hottest functions")
    args = ap.parse_args(argv)
    res = run(args.scenario, args.epochs, args.redis_url, args.profile)
    med = res["median_ms"]
    print(
        f"{res['scenario']} on {res['store']}, {res['epochs']} epochs, medians (ms): "
        + ", ".join(f"{k} {med[k]:.2f}" for k in (*STAGES, "total"))
        + f"; everything but decide {res['besides_decide_ms']:.2f}"
    )
    if args.profile:
        print(res["profile"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
