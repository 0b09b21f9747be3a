"""Use cases: turn validated requests into calls on the core and the store (exactly-once epochs)."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import logging
import math
import re
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from app.errors import (
    Busy,
    EpochConflict,
    FieldIssue,
    InvalidInput,
    NoData,
    StaleEpoch,
    TaskConflict,
)
from app.ports import CityState, EpochCommit, Store, StoredEpoch
from app.schemas import (
    CellCountOut,
    CoverageOut,
    EpochIn,
    EpochOut,
    GraphEdgeOut,
    GraphNodeOut,
    GraphOut,
    LocationIn,
    RiderMatchOut,
    TaskAssignmentOut,
    TaskIn,
    TaskOut,
    TasksPutOut,
    format_time,
    parse_rfc3339,
)
from services.city import City
from services.model import (
    CountsView,
    Decision,
    IntervalKey,
    Rider,
    RiderId,
    Snapshot,
    Task,
    TaskId,
    Taxi,
    TaxiId,
)
from services.network import SnapError
from services.sensing import coverage_rate, gamma

__all__ = [
    "CityCatalog",
    "DecideFn",
    "Limits",
    "EpochOutcome",
    "DispatchService",
    "body_hash",
    "LOOKAHEAD_INTERVALS",
]

log = logging.getLogger(__name__)

LOOKAHEAD_INTERVALS = 2  # intervals after the epoch's own that are loaded before solving
_LABEL = re.compile(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}$")

DecideFn = Callable[[City, CountsView, Snapshot, Sequence[Task]], Decision]


class CityCatalog(Protocol):
    """The served cities (implemented by ``app.cities.CityRegistry``)."""

    def names(self) -> list[str]: ...

    def get(self, name: str) -> City:
        """The city; raises ``app.errors.UnknownCityError`` (or a subclass) when not served."""


@dataclass(frozen=True, slots=True)
class Limits:
    """Per-request size limits (from settings)."""

    max_riders: int = 2000
    max_taxis: int = 5000
    max_tasks: int = 1000


@dataclass(frozen=True, slots=True)
class EpochOutcome:
    """The response of one epoch post and what it changed (nothing when ``replayed``)."""

    response_json: str
    replayed: bool
    matches_by_step: dict[int, int] = field(default_factory=dict)
    n_task_assignments: int = 0
    attempts: int = 0


def body_hash(body: EpochIn) -> str:
    """sha256 of the canonical JSON of a validated epoch body."""
    canonical = json.dumps(body.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()


def _dense(city: City, sparse: dict[int, int]) -> NDArray[np.int64]:
    arr = np.zeros(city.grid.n_cells, dtype=np.int64)
    if sparse:
        cells = np.fromiter(sparse.keys(), dtype=np.int64, count=len(sparse))
        arr[cells] = np.fromiter(sparse.values(), dtype=np.int64, count=len(sparse))
    return arr


def _counts_view(city: City, state: CityState, intervals: Sequence[IntervalKey]) -> CountsView:
    return CountsView(
        counts={k: _dense(city, state.counts.get(k, {})) for k in intervals},
        visited={taxi: frozenset(pairs) for taxi, pairs in state.visited.items()},
    )


def _gamma_before_after(
    city: City, counts: CountsView, decision: Decision, day: Sequence[IntervalKey]
) -> tuple[float, float]:
    """Gamma over the day's horizon intervals at the epoch's start and once its visits are counted."""
    after = {k: arr.copy() for k, arr in counts.counts.items()}
    for visit in decision.visits:  # each visit is a new (taxi, interval, cell): Lambda + 1
        arr = after.get(visit.interval)
        if arr is not None:
            arr[visit.cell] += 1
    return gamma(city, counts.counts, day), gamma(city, after, day)


class DispatchService:
    """The use cases of the API: cities, tasks, epochs and coverage over one store."""

    def __init__(
        self,
        cities: CityCatalog,
        store: Store,
        decide: DecideFn,
        *,
        limits: Limits | None = None,
        retention_s: int = 8 * 86400,
        commit_attempts: int = 8,
    ) -> None:
        self.cities = cities
        self.store = store
        self.decide = decide
        self.limits = limits or Limits()
        self.retention_s = retention_s
        self.commit_attempts = commit_attempts
        self._graph_cache: dict[str, bytes] = {}
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ cities

    def city(self, name: str) -> City:
        """The city called ``name`` (the catalog raises ``UnknownCityError``, a 404, when not served)."""
        return self.cities.get(name)

    def city_names(self) -> list[str]:
        """Names of the served cities."""
        return sorted(self.cities.names())

    def graph_json(self, name: str) -> bytes:
        """The city's network as GraphOut JSON (cached: cities are immutable)."""
        with self._lock:
            cached = self._graph_cache.get(name)
        if cached is not None:
            return cached
        city = self.city(name)
        net, grid = city.network, city.grid
        col = np.floor((net.x_m - grid.origin_x_m) / grid.cell_m).astype(np.int64)
        row = np.floor((net.y_m - grid.origin_y_m) / grid.cell_m).astype(np.int64)
        ids = net.node_ids
        graph = GraphOut(
            nodes=[
                GraphNodeOut(id=int(i), lon=float(lo), lat=float(la), cell=(int(c), int(r)))
                for i, lo, la, c, r in zip(
                    ids.tolist(), net.lon.tolist(), net.lat.tolist(), col.tolist(), row.tolist(), strict=True
                )
            ],
            edges=[
                GraphEdgeOut(u=int(ids[u]), v=int(ids[v]), length_m=float(length), travel_time_s=float(t))
                for u, v, length, t in zip(
                    net.edge_u.tolist(),
                    net.edge_v.tolist(),
                    net.edge_length_m.tolist(),
                    net.edge_time_s.tolist(),
                    strict=True,
                )
            ],
        )
        data = graph.model_dump_json().encode()
        with self._lock:
            self._graph_cache[name] = data
        return data

    # ------------------------------------------------------------------ inputs

    @staticmethod
    def _resolve(city: City, loc: LocationIn, where: str) -> int:
        """Node index of a location; 422 naming ``where`` when it is unknown or off the network."""
        if loc.node is not None:
            try:
                return city.network.index_of(loc.node)
            except SnapError:
                raise InvalidInput.at(f"{where}.node", f"unknown node id {loc.node}") from None
        assert loc.lon is not None and loc.lat is not None
        try:
            node, _ = city.network.snap(loc.lon, loc.lat, city.params.snap_limit_m)
        except SnapError:
            raise InvalidInput.at(
                where,
                f"({loc.lon}, {loc.lat}) is farther than {city.params.snap_limit_m:.0f} m from every node",
            ) from None
        return node

    @staticmethod
    def _unique(ids: Sequence[str], where: str) -> None:
        """422 naming the first id that repeats an earlier one."""
        seen: set[str] = set()
        for i, ident in enumerate(ids):
            if ident in seen:
                raise InvalidInput.at(f"{where}[{i}].id", f"duplicate id {ident!r}")
            seen.add(ident)

    @staticmethod
    def _at_most(n: int, limit: int, where: str) -> None:
        if n > limit:
            raise InvalidInput.at(where, f"at most {limit} items per request, got {n}")

    def _snapshot(self, city: City, body: EpochIn) -> Snapshot:
        """Validate an epoch body against the city and resolve it to node indices (no store access)."""
        self._at_most(len(body.riders), self.limits.max_riders, "riders")
        self._at_most(len(body.taxis), self.limits.max_taxis, "taxis")
        self._unique([r.id for r in body.riders], "riders")
        self._unique([t.id for t in body.taxis], "taxis")
        time_s = body.time.timestamp()
        riders: list[Rider] = []
        for i, r in enumerate(body.riders):
            requested_s = r.requested_at.timestamp()
            if requested_s > time_s:
                raise InvalidInput.at(f"riders[{i}].requested_at", "is later than the epoch time")
            riders.append(
                Rider(
                    id=RiderId(r.id),
                    origin=self._resolve(city, r.origin, f"riders[{i}].origin"),
                    destination=self._resolve(city, r.destination, f"riders[{i}].destination"),
                    requested_at_s=requested_s,
                )
            )
        taxis = tuple(
            Taxi(
                id=TaxiId(t.id),
                node=self._resolve(city, t.location, f"taxis[{i}].location"),
                instrumented=t.instrumented,
                vacant=t.status == "vacant",
            )
            for i, t in enumerate(body.taxis)
        )
        return Snapshot(epoch_id=body.epoch_id, time_s=time_s, riders=tuple(riders), taxis=taxis)

    # ------------------------------------------------------------------ tasks

    def put_tasks(self, name: str, tasks: Sequence[TaskIn]) -> TasksPutOut:
        """Register tasks, idempotent per id (409 naming conflicting ids; nothing written then)."""
        city = self.city(name)
        self._at_most(len(tasks), self.limits.max_tasks, "body")
        self._unique([t.id for t in tasks], "")
        core: list[Task] = []
        for i, t in enumerate(tasks):
            node = self._resolve(city, t.location, f"[{i}].location")
            where = (
                None if t.location.lon is None or t.location.lat is None else (t.location.lon, t.location.lat)
            )
            core.append(
                Task(id=TaskId(t.id), node=node, scheduled_at_s=t.scheduled_at.timestamp(), location=where)
            )
        result = self.store.put_tasks(name, core)
        if result.conflicts:
            index = {t.id: i for i, t in enumerate(tasks)}
            raise TaskConflict(
                "tasks exist with different content: " + ", ".join(map(str, result.conflicts)),
                [
                    FieldIssue(f"[{index[c]}].id", f"task {c!r} exists with different content")
                    for c in result.conflicts
                ],
            )
        return TasksPutOut(
            created=[str(t) for t in result.created], unchanged=[str(t) for t in result.unchanged]
        )

    def list_tasks(self, name: str) -> list[TaskOut]:
        """All tasks of a city, in scheduled order."""
        city = self.city(name)
        tasks = sorted(self.store.list_tasks(name), key=lambda t: (t.scheduled_at_s, t.id))
        return [TaskOut.of(city, t) for t in tasks]

    # ------------------------------------------------------------------ epochs

    def _replay(self, stored: StoredEpoch, digest: str) -> EpochOutcome:
        if stored.body_hash != digest:
            raise EpochConflict(
                f"epoch {stored.epoch_id!r} was committed with a different body",
                [FieldIssue("epoch_id", "already used with a different body")],
            )
        return EpochOutcome(response_json=stored.response_json, replayed=True)

    def _load(
        self, name: str, intervals: set[IntervalKey], taxi_ids: Sequence[TaxiId], time_s: float
    ) -> CityState:
        state = self.store.load_state(name, sorted(intervals), taxi_ids)
        if state.last_epoch_time_s is not None and time_s < state.last_epoch_time_s:
            raise StaleEpoch(
                f"epoch time is older than the last committed epoch {state.last_epoch_id!r}",
                [FieldIssue("time", "older than the last committed epoch")],
            )
        return state

    def submit_epoch(self, name: str, body: EpochIn) -> EpochOutcome:
        """Solve and commit one epoch exactly once (docs/DESIGN.md, "Exactly-once epochs")."""
        city = self.city(name)
        snapshot = self._snapshot(city, body)
        digest = body_hash(body)
        stored = self.store.get_epoch(name, body.epoch_id)
        if stored is not None:
            return self._replay(stored, digest)

        k0 = city.horizon.interval_of(snapshot.time_s)
        day = city.horizon.day_intervals(k0)
        # the epoch's interval and the next two (paths run on), plus the day's horizon for Gamma
        intervals = {IntervalKey(k0 + i) for i in range(LOOKAHEAD_INTERVALS + 1)} | set(day)
        instrumented = [t.id for t in snapshot.taxis if t.instrumented]
        for attempt in range(1, self.commit_attempts + 1):
            state = self._load(name, intervals, instrumented, snapshot.time_s)
            started = time.perf_counter()
            while True:
                counts = _counts_view(city, state, sorted(intervals))
                decision = self.decide(city, counts, snapshot, state.tasks)
                missing = set(decision.intervals_touched) - intervals
                if not missing:
                    break
                intervals |= missing  # the solve reached intervals it read as zero: load them, solve again
                state = self._load(name, intervals, instrumented, snapshot.time_s)
            solve_ms = (time.perf_counter() - started) * 1000.0
            gammas = _gamma_before_after(city, counts, decision, day)
            response = self._render(city, body, decision, k0, solve_ms, attempt, gammas)
            result = self.store.commit_epoch(
                name,
                EpochCommit(
                    epoch_id=body.epoch_id,
                    body_hash=digest,
                    time_s=snapshot.time_s,
                    expected_version=state.version,
                    visits=decision.visits,
                    task_updates=decision.task_updates,
                    response_json=response,
                    retention_s=self.retention_s,
                    demand_json=self._demand(city, body, snapshot),
                ),
            )
            if result.status == "committed":
                steps = {1: 0, 2: 0}
                for m in decision.rider_matches:
                    steps[m.step] += 1
                return EpochOutcome(response, False, steps, len(decision.task_assignments), attempt)
            if result.status == "duplicate":
                if result.stored is None:
                    raise RuntimeError("store reported a duplicate epoch without its record")
                return self._replay(result.stored, digest)
            if result.status == "stale":
                raise StaleEpoch(
                    "epoch time is older than the last committed epoch",
                    [FieldIssue("time", "older than the last committed epoch")],
                )
            log.info(
                "epoch %s of %s: version mismatch on attempt %d, solving again", body.epoch_id, name, attempt
            )
        raise Busy(
            f"city {name!r} is busy: {self.commit_attempts} commit attempts lost to concurrent epochs; retry"
        )

    @staticmethod
    def _render(
        city: City,
        body: EpochIn,
        decision: Decision,
        k0: IntervalKey,
        solve_ms: float,
        attempt: int,
        gammas: tuple[float, float],
    ) -> str:
        """The response document of a decided epoch (stored verbatim for replays)."""
        stats: dict[str, float | int | str] = {}
        for key, value in decision.stats.items():
            v: Any = value
            if isinstance(v, bool | np.bool_ | int | np.integer):
                stats[key] = int(v)
            elif isinstance(v, float | np.floating):
                if math.isfinite(v):  # JSON has no NaN or infinity
                    stats[key] = float(v)
            elif isinstance(v, str):
                stats[key] = v
        stats.update(
            {
                "step1_matches": sum(1 for m in decision.rider_matches if m.step == 1),
                "step2_matches": sum(1 for m in decision.rider_matches if m.step == 2),
                "task_assignments": len(decision.task_assignments),
                "tasks_completed": len(decision.tasks_completed),
                "riders": len(body.riders),
                "taxis": len(body.taxis),
                "interval": city.horizon.label(k0),
                "interval_key": int(k0),
                "in_horizon": int(city.horizon.in_horizon(k0)),
                "solve_ms": round(solve_ms, 3),
                "attempts": attempt,
                "visits": len(decision.visits),
                "gamma": gammas[1],
                "gamma_gain": gammas[1] - gammas[0],
            }
        )
        out = EpochOut(
            epoch_id=body.epoch_id,
            time=body.time.isoformat(),
            rider_matches=[RiderMatchOut.of(city, m) for m in decision.rider_matches],
            task_assignments=[TaskAssignmentOut.of(city, a) for a in decision.task_assignments],
            tasks_completed=[TaskOut.of(city, t) for t in decision.tasks_completed],
            unmatched_rider_ids=[str(r) for r in decision.unmatched_rider_ids],
            expired_rider_ids=[str(r) for r in decision.expired_rider_ids],
            stats=stats,
        )
        return out.model_dump_json()

    @staticmethod
    def _demand(city: City, body: EpochIn, snapshot: Snapshot) -> str:
        """The epoch's riders for the fleet-sizing worker (a waiting rider recurs: dedupe by id)."""
        ids = city.network.node_ids
        doc: dict[str, Any] = {
            "epoch_id": body.epoch_id,
            "time": body.time.isoformat(),
            "time_s": snapshot.time_s,
            "riders": [
                {
                    "id": str(r.id),
                    "origin": int(ids[r.origin]),
                    "destination": int(ids[r.destination]),
                    "requested_at": format_time(r.requested_at_s, city.horizon.timezone),
                    "requested_at_s": r.requested_at_s,
                }
                for r in snapshot.riders
            ],
        }
        return json.dumps(doc, separators=(",", ":"))

    # ------------------------------------------------------------------ coverage

    @staticmethod
    def parse_interval(city: City, text: str) -> IntervalKey:
        """An interval from its label (``YYYY-MM-DDTHH:MM``, local start) or any RFC 3339 time inside it."""
        hz = city.horizon
        if _LABEL.match(text):
            try:
                local = dt.datetime.strptime(text, "%Y-%m-%dT%H:%M")
            except ValueError:
                raise InvalidInput.at("interval", "not a valid date and time") from None
            start_s = hz.start.hour * 3600 + hz.start.minute * 60 + hz.start.second
            local_s = (local - dt.datetime(1970, 1, 1)).total_seconds()
            k = IntervalKey(math.floor((local_s - start_s) / hz.interval_s))
            if hz.label(k) != text:
                raise InvalidInput.at(
                    "interval", f"{text} is not the start of an interval (e.g. {hz.label(k)})"
                )
            return k
        try:
            when = parse_rfc3339(text)
        except ValueError as exc:
            raise InvalidInput.at(
                "interval", f"give a label YYYY-MM-DDTHH:MM or an RFC 3339 time with an offset ({exc})"
            ) from None
        return hz.interval_of(when.timestamp())

    def coverage(self, name: str, interval: str | None) -> CoverageOut:
        """Lambda per cell, coverage rate and Gamma so far for one interval (default: the last epoch's)."""
        city = self.city(name)
        if interval is not None:
            k = self.parse_interval(city, interval)
        else:
            state = self.store.load_state(name, [], [])
            if state.last_epoch_time_s is None:
                raise NoData(f"no epoch committed for {name!r} yet; pass ?interval=")
            k = city.horizon.interval_of(state.last_epoch_time_s)
        day = city.horizon.day_intervals(k)
        wanted = sorted(set(day) | {k})
        counts = {j: _dense(city, self.store.interval_counts(name, j)) for j in wanted}
        arr = counts[k]
        nz = np.flatnonzero(arr)
        return CoverageOut(
            city=name,
            interval=city.horizon.label(k),
            interval_key=int(k),
            in_horizon=city.horizon.in_horizon(k),
            cells=[CellCountOut(cell=city.grid.col_row(int(c)), count=int(arr[c])) for c in nz],
            coverage_rate=coverage_rate(city, arr),
            gamma_so_far=gamma(city, counts, day),
            n_cells_covered=int(nz.size),
            n_cells_touched=int(np.count_nonzero(city.cell_weight > 0)),
        )
