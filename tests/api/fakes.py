"""A tiny hand-built city near Chengdu and a transparent fake ``decide`` for testing the plumbing."""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from services.city import City
from services.citydata import CityMeta, save_bundle
from services.model import (
    CountsView,
    Decision,
    IntervalKey,
    RiderMatch,
    Snapshot,
    Task,
    Visit,
)
from services.network.network import build_network

CITY = "tiny"
N = 5  # 5 x 5 lattice
SPACING_M = 400.0
LON0, LAT0 = 104.06, 30.66
NODE0 = 1000  # node id of (col, row) is NODE0 + row * N + col
TZ = dt.timezone(dt.timedelta(hours=8))
T0 = dt.datetime(2026, 11, 23, 8, 0, tzinfo=TZ)  # start of the first horizon interval


def node_id(col: int, row: int) -> int:
    """External id of the lattice node at (col, row)."""
    return NODE0 + row * N + col


def lonlat(col: float, row: float) -> tuple[float, float]:
    """Approximate lon/lat of lattice position (col, row)."""
    dlon = SPACING_M / (111_320.0 * np.cos(np.radians(LAT0)))
    dlat = SPACING_M / 110_574.0
    return LON0 + col * dlon, LAT0 + row * dlat


def build_bundle(root: Path) -> Path:
    """Write the tiny city's bundle under ``root/tiny`` and return ``root``."""
    ids, lons, lats = [], [], []
    for row in range(N):
        for col in range(N):
            lon, lat = lonlat(col, row)
            ids.append(node_id(col, row))
            lons.append(lon)
            lats.append(lat)
    us, vs, lengths = [], [], []
    for row in range(N):
        for col in range(N):
            for dc, dr in ((1, 0), (0, 1)):
                c2, r2 = col + dc, row + dr
                if c2 < N and r2 < N:
                    us += [node_id(col, row), node_id(c2, r2)]
                    vs += [node_id(c2, r2), node_id(col, row)]
                    lengths += [SPACING_M, SPACING_M]
    net = build_network(ids, lons, lats, us, vs, lengths)
    meta = CityMeta(name=CITY, timezone="Asia/Shanghai", start="08:00", source="hand-built test lattice")
    save_bundle(root / CITY, net, meta)
    return root


def rfc(t: dt.datetime) -> str:
    """RFC 3339 text."""
    return t.isoformat()


def _node_cells(city: City, path: Sequence[int]) -> list[int]:
    g = city.grid
    out: list[int] = []
    for v in path:
        col = int((city.network.x_m[v] - g.origin_x_m) // g.cell_m)
        row = int((city.network.y_m[v] - g.origin_y_m) // g.cell_m)
        cell = row * g.n_cols + col
        if cell not in out:
            out.append(cell)
    return out


class FakeDecide:
    """Greedy, obvious stand-in for ``services.dispatch.decide``: riders in order take the first vacant
    taxi; an instrumented taxi counts the cells of its path nodes in the epoch's interval and completes
    (passively) any open task on them. Records every call."""

    def __init__(self, extra_intervals: Sequence[int] = (), fail: Exception | None = None) -> None:
        self.calls: list[dict[str, Any]] = []
        self.extra_intervals = tuple(extra_intervals)
        self.fail = fail

    def __call__(self, city: City, counts: CountsView, snapshot: Snapshot, tasks: Sequence[Task]) -> Decision:
        self.calls.append({"intervals": sorted(counts.counts), "counts": counts, "tasks": list(tasks)})
        if self.fail is not None:
            raise self.fail
        k = city.horizon.interval_of(snapshot.time_s)
        vacant = [t for t in snapshot.taxis if t.vacant]
        matches: list[RiderMatch] = []
        visits: list[Visit] = []
        unmatched, expired = [], []
        updates: list[Task] = []
        for rider in snapshot.riders:
            if snapshot.time_s - rider.requested_at_s > city.params.patience_s:
                expired.append(rider.id)
                continue
            if not vacant:
                unmatched.append(rider.id)
                continue
            taxi = vacant.pop(0)
            path = tuple(dict.fromkeys((taxi.node, rider.origin, rider.destination)))
            cells = _node_cells(city, path)
            if taxi.instrumented:
                seen = counts.visited.get(taxi.id, frozenset())
                visits += [Visit(taxi.id, IntervalKey(k), c) for c in cells if (k, c) not in seen]
                for task in tasks:
                    if task.is_open(snapshot.time_s) and task.node in path:
                        updates.append(
                            replace(
                                task,
                                status="completed",
                                completed_at_s=snapshot.time_s,
                                taxi_id=taxi.id,
                                mode="passive",
                            )
                        )
            matches.append(
                RiderMatch(
                    step=1 if taxi.instrumented else 2,
                    taxi_id=taxi.id,
                    rider_id=rider.id,
                    pickup_m=100.0,
                    wait_s=10.0,
                    trip_m=800.0,
                    trip_time_s=82.0,
                    sensing_gain=0.5 if taxi.instrumented else 0.0,
                    path=path,
                    cells=tuple(city.grid.col_row(c) for c in cells),
                )
            )
        touched = sorted({IntervalKey(k)} | {IntervalKey(k + d) for d in self.extra_intervals})
        return Decision(
            epoch_id=snapshot.epoch_id,
            time_s=snapshot.time_s,
            rider_matches=tuple(matches),
            task_assignments=(),
            tasks_completed=tuple(updates),
            task_updates=tuple(updates),
            unmatched_rider_ids=tuple(unmatched),
            expired_rider_ids=tuple(expired),
            visits=tuple(visits),
            intervals_touched=tuple(touched),
            stats={
                "gamma": 0.25,
                "n_candidates": len(matches),
                # what decide counts for Decision.matches_by_step
                "step1_matches": sum(1 for m in matches if m.step == 1),
                "step2_matches": sum(1 for m in matches if m.step == 2),
            },
        )
