"""``python -m app demo``: the first epochs of a simulated Chengdu morning posted to the service (one started
in this process, or ``--url``), each decision printed as it comes back.

The demo is a short replay: the simulator (``services.sim.engine.simulate``) drives the service through the
replay client (``app.entrypoints.replay_client.HttpDispatcher``) on the city's demand generator;
``Narrator`` only prints what passes between them.
"""

from __future__ import annotations

import datetime as dt
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TextIO
from zoneinfo import ZoneInfo

import httpx
import numpy as np
from numpy.typing import NDArray

from app.adapters.city_registry import CityRegistry
from app.entrypoints.replay_client import HttpDispatcher, ReplayError, service_client
from app.runs import RunSpec, demand_for, open_bundle
from app.settings import Settings
from services.city import City
from services.model import IntervalKey, Snapshot, Task
from services.sim.demand import demand_on_date
from services.sim.engine import SimConfig, poi_tasks, simulate
from services.sim.local import Outcome

__all__ = ["DemoConfig", "Narrator", "run_demo"]

_TASK_STREAM = 0xDE0
_EARLY_TASK_S = 600  # tasks open up to ten minutes before the first epoch


@dataclass(frozen=True, slots=True)
class DemoConfig:
    """What ``python -m app demo`` simulates: ``riders`` is the mean number of new requests per epoch."""

    city: str = "chengdu"
    epochs: int = 5
    riders: int = 12
    taxis: int = 30
    instrumented_share: float = 0.5
    tasks: int = 4
    seed: int = 7
    date: str = "2026-11-23"

    @property
    def prefix(self) -> str:
        """Prefix of the demo's taxi, rider, task and epoch ids (keeps them apart on a shared service)."""
        return f"demo{self.seed}-"


class Narrator:
    """A dispatcher that passes everything to ``inner`` (the HTTP replay client) and prints each decision."""

    def __init__(self, inner: HttpDispatcher, n_epochs: int, prefix: str, out: TextIO) -> None:
        self.inner = inner
        self.n_epochs = n_epochs
        self.prefix = prefix
        self.out = out
        self.done = 0
        self._zone = ZoneInfo(inner.city.horizon.timezone)

    def add_tasks(self, tasks: Sequence[Task]) -> None:
        self.inner.add_tasks(tasks)
        print(f"registered {len(tasks)} monitoring tasks", file=self.out)

    def epoch(self, snapshot: Snapshot) -> Outcome:
        outcome = self.inner.epoch(snapshot)
        self.done += 1
        when = dt.datetime.fromtimestamp(snapshot.time_s, self._zone)
        replay = " (replayed: this epoch was committed before)" if self.inner.last_replayed else ""
        n_vacant = sum(1 for t in snapshot.taxis if t.vacant)
        n_instr = sum(1 for t in snapshot.taxis if t.instrumented)
        head = (
            f"epoch {self.done}/{self.n_epochs} at {when:%H:%M:%S}{replay}: {len(snapshot.riders)} riders "
            f"waiting, {len(snapshot.taxis)} taxis ({n_vacant} vacant, {n_instr} instrumented)"
        )
        assert self.inner.last_response is not None
        _print_epoch(self.out, head, self.inner.last_response, self.prefix)
        return outcome

    def tasks(self) -> list[Task]:
        return self.inner.tasks()

    def interval_counts(self, k: IntervalKey) -> NDArray[np.int64]:
        return self.inner.interval_counts(k)


def _print_epoch(out: TextIO, head: str, res: dict[str, Any], prefix: str) -> None:
    """A readable summary of one epoch's response document."""

    def short(name: object) -> str:
        return str(name).removeprefix(prefix)

    print(f"\n{head}", file=out)
    for step, label in ((1, "instrumented taxis -> riders"), (2, "regular taxis -> riders")):
        ms = [m for m in res["rider_matches"] if m["step"] == step]
        wait = f"mean wait {np.mean([m['wait_s'] for m in ms]):4.0f} s" if ms else ""
        gain = f"  sensing gain {sum(m['sensing_gain'] for m in ms):.4f}" if step == 1 and ms else ""
        print(f"  step {step}  {label:30s} {len(ms):3d} matches  {wait}{gain}", file=out)
    routes = ", ".join(
        f"{short(a['taxi_id'])} -> {short(a['task_id'])} ({a['length_m'] / 1000:.1f} km, "
        f"{a['travel_time_s'] / 60:.1f} min, {a['cost_cny']:.2f} CNY)"
        for a in res["task_assignments"]
    )
    print(f"  step 3  {'POI monitoring routes':30s} {len(res['task_assignments']):3d}  {routes}", file=out)
    if res["tasks_completed"]:
        done = ", ".join(
            f"{short(t['id'])} ({t['mode']}, {short(t['taxi_id'])})" for t in res["tasks_completed"]
        )
        print(f"  tasks completed: {done}", file=out)
    st = res["stats"]
    print(
        f"  unmatched {len(res['unmatched_rider_ids'])}, expired {len(res['expired_rider_ids'])}"
        f" | Gamma {st.get('gamma', 0.0):.5f} (+{st.get('gamma_gain', 0.0):.5f})"
        f" | solved in {st.get('solve_ms', 0.0):.0f} ms",
        file=out,
    )


def run_demo(
    config: DemoConfig, url: str | None = None, token: str | None = None, out: TextIO | None = None
) -> int:
    """Post the first ``config.epochs`` epochs of a simulated morning and print what was decided."""
    stream = out or sys.stdout
    if url is not None and not token:
        print("demo: --token is required with --url", file=sys.stderr)
        return 2
    bundle = open_bundle(CityRegistry.from_settings(Settings()).bundle_dir(config.city))
    city = bundle.city
    hz = city.horizon
    n_epochs = hz.length_s // hz.epoch_s
    if not 1 <= config.epochs <= n_epochs:
        print(f"demo: --epochs must lie in 1..{n_epochs} (one horizon)", file=sys.stderr)
        return 2
    n1 = round(config.taxis * config.instrumented_share)
    rate = config.riders * 3600.0 / hz.epoch_s
    spec = RunSpec(config.city, n1=n1, n0=config.taxis - n1, seed=config.seed, rate_per_hour=rate)
    demand = demand_on_date(demand_for(spec, bundle), hz, config.date)
    # the tasks open during the epochs shown, so Step 3 has POIs to route to
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, _TASK_STREAM]))
    window_s = config.epochs * hz.epoch_s + _EARLY_TASK_S
    start_s = hz.start_s(config.date) - _EARLY_TASK_S
    tasks = poi_tasks(bundle.candidates, config.tasks, start_s, window_s, rng, config.prefix)
    sim = SimConfig(
        n_instrumented=n1,
        n_ordinary=config.taxis - n1,
        n_tasks=config.tasks,
        seed=config.seed,
        id_prefix=config.prefix,
    )
    net = city.network
    with service_client(url, token, stream) as client:
        print(
            f"city {city.name}: {net.n_nodes} nodes, {net.n_edges} edges, "
            f"{float(net.edge_length_m.sum()) / 1000:.0f} km of road; grid {city.grid.n_cols} x "
            f"{city.grid.n_rows} cells; {len(demand.requests)} requests over the morning "
            f"({rate:.0f} per hour); seed {config.seed}",
            file=stream,
        )
        narrator = Narrator(HttpDispatcher(client, config.city, city), config.epochs, config.prefix, stream)
        try:
            trace = simulate(city, demand, tasks, sim, narrator, n_epochs=config.epochs)
        except ReplayError as exc:
            if exc.status_code == 409:
                print(
                    "demo: the service already holds later or different epochs of this city; pass another "
                    f"--date ({exc})",
                    file=sys.stderr,
                )
            else:
                print(f"demo: {exc}", file=sys.stderr)
            return 1
        _print_coverage(client, city, stream)
    counts = {s: sum(1 for t in trace.tasks if t.status == s) for s in ("pending", "assigned", "completed")}
    print(
        f"tasks: {counts['completed']} completed, {counts['assigned']} on their way, "
        f"{counts['pending']} pending",
        file=stream,
    )
    return 0


def _print_coverage(client: httpx.Client, city: City, out: TextIO) -> None:
    """The grid counts of the last epoch's interval, as the coverage endpoint reports them."""
    r = client.get(f"/v1/cities/{city.name}/coverage")
    if r.status_code == 200:
        cov = r.json()
        print(
            f"\ncoverage of interval {cov['interval']}: {cov['n_cells_covered']} of "
            f"{cov['n_cells_touched']} cells sensed ({cov['coverage_rate']:.0%}), "
            f"Gamma so far {cov['gamma_so_far']:.5f}",
            file=out,
        )
