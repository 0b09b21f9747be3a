"""The epoch response document: ``render_epoch`` (plain values, encoded once) writes byte for byte what the
validated response models write (``reference_render`` below renders through them), on real decisions and on
decisions with awkward values (numpy scalars, NaN and infinities, missing optional task fields, non-ASCII
ids); every document it writes validates as ``EpochOut`` unchanged; the paths read their own network's node
ids when many threads render at once."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import pytest

from app.schemas.decision import EpochOut, RiderMatchOut, TaskAssignmentOut
from app.schemas.tasks import TaskOut
from app.usecases import EpochCommand, EpochResult
from app.usecases.epoch_record import _core_stats, _ext_paths, epoch_doc, render_epoch
from services.city import City
from services.dispatch import decide
from services.model import (
    CountsView,
    Decision,
    IntervalKey,
    Rider,
    RiderId,
    RiderMatch,
    Snapshot,
    Task,
    TaskAssignment,
    TaskId,
    Taxi,
    TaxiId,
)
from services.rfc3339 import format_time
from tests.citymaker import T0, grid_city


def _ref_path(city: City, path: tuple[int, ...]) -> list[int]:
    return [int(v) for v in city.network.node_ids[list(path)]] if path else []


def _ref_cells(cells: tuple[tuple[int, int], ...]) -> list[tuple[int, int]]:
    return [(int(c), int(r)) for c, r in cells]


def _ref_task(city: City, task: Task) -> TaskOut:
    tz = city.horizon.timezone
    return TaskOut(
        id=str(task.id),
        node=int(city.network.node_ids[task.node]),
        status=task.status,
        scheduled_at=format_time(task.scheduled_at_s, tz),
        completed_at=None if task.completed_at_s is None else format_time(task.completed_at_s, tz),
        taxi_id=None if task.taxi_id is None else str(task.taxi_id),
        mode=task.mode,
    )


def reference_render(result: EpochResult) -> str:
    """The renderer as it was: every part built and validated as a response model, then dumped."""
    city, decision, snapshot = result.city, result.decision, result.epoch.snapshot
    stats = _core_stats(decision)
    stats.update(
        {
            "step1_matches": sum(1 for m in decision.rider_matches if m.step == 1),
            "step2_matches": sum(1 for m in decision.rider_matches if m.step == 2),
            "task_assignments": len(decision.task_assignments),
            "tasks_completed": len(decision.tasks_completed),
            "riders": len(snapshot.riders),
            "taxis": len(snapshot.taxis),
            "interval": city.horizon.label(result.interval),
            "interval_key": int(result.interval),
            "in_horizon": int(city.horizon.in_horizon(result.interval)),
            "solve_ms": round(result.solve_ms, 3),
            "attempts": result.attempts,
            "visits": len(decision.visits),
            "gamma": result.gamma_after,
            "gamma_gain": result.gamma_after - result.gamma_before,
        }
    )
    out = EpochOut(
        epoch_id=snapshot.epoch_id,
        time=result.epoch.time_text,
        rider_matches=[
            RiderMatchOut(
                step=m.step,
                taxi_id=str(m.taxi_id),
                rider_id=str(m.rider_id),
                pickup_m=float(m.pickup_m),
                wait_s=float(m.wait_s),
                trip_m=float(m.trip_m),
                trip_time_s=float(m.trip_time_s),
                sensing_gain=float(m.sensing_gain),
                path=_ref_path(city, m.path),
                cells=_ref_cells(m.cells),
            )
            for m in decision.rider_matches
        ],
        task_assignments=[
            TaskAssignmentOut(
                taxi_id=str(a.taxi_id),
                task_id=str(a.task_id),
                path=_ref_path(city, a.path),
                cells=_ref_cells(a.cells),
                length_m=float(a.length_m),
                travel_time_s=float(a.travel_time_s),
                sensing_gain=float(a.sensing_gain),
                efficiency=float(a.efficiency),
                cost_cny=float(a.cost_cny),
                kappa=float(a.kappa),
            )
            for a in decision.task_assignments
        ],
        tasks_completed=[_ref_task(city, t) for t in decision.tasks_completed],
        unmatched_rider_ids=[str(r) for r in decision.unmatched_rider_ids],
        expired_rider_ids=[str(r) for r in decision.expired_rider_ids],
        stats=stats,
    )
    return out.model_dump_json()


def _result(city: City, decision: Decision, snapshot: Snapshot, **kw: Any) -> EpochResult:
    args: dict[str, Any] = {
        "interval": IntervalKey(city.horizon.interval_of(snapshot.time_s)),
        "solve_ms": 12.3456789,
        "attempts": 1,
        "gamma_before": 0.25,
        "gamma_after": 0.5,
    } | kw
    return EpochResult(city, EpochCommand(snapshot, "h", "2026-11-23T08:00:10+08:00"), decision, **args)


def _check(result: EpochResult, *, finite: bool = True) -> str:
    text = render_epoch(result)
    assert text == reference_render(result)
    assert EpochOut.of(result).model_dump_json() == text
    if finite:  # NaN and infinities are written as null, which does not read back as a number
        assert EpochOut.model_validate_json(text).model_dump_json() == text
    return text


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_real_decisions_render_as_the_validated_models_do(seed: int) -> None:
    city = grid_city(8, 300.0, cell_m=500.0)
    rng = np.random.default_rng(seed)
    n = city.network.n_nodes
    now = T0 + 30.0
    taxis = tuple(Taxi(TaxiId(f"t{i}"), int(rng.integers(n)), i % 3 > 0, i % 7 > 0) for i in range(24))
    riders = tuple(
        Rider(RiderId(f"r{i}"), int(rng.integers(n)), int(rng.integers(n)), now - float(rng.uniform(0, 200)))
        for i in range(4)
    )
    tasks = [Task(TaskId(f"k{i}"), int(rng.integers(n)), now - 60.0) for i in range(4)]
    snapshot = Snapshot(f"e{seed}", now, riders, taxis)
    decision = decide(city, CountsView({}), snapshot, tasks)
    assert decision.rider_matches and decision.task_assignments  # the document has both kinds of rows
    _check(_result(city, decision, snapshot))


def test_awkward_values_render_as_the_validated_models_do() -> None:
    city = grid_city(3, 300.0, cell_m=500.0)
    snapshot = Snapshot("é-1", T0, (), (Taxi(TaxiId("t"), 0, True, True),))
    match = RiderMatch(
        np.int64(1),  # type: ignore[arg-type]
        TaxiId("taxi-ü"),
        RiderId("r\u2028"),
        np.float64(0.0),
        np.float32(1.5),  # type: ignore[arg-type]
        400.0,
        math.nan,
        math.inf,
        (np.int64(0), 1, np.int32(2)),  # type: ignore[arg-type]
        ((np.int64(0), np.int64(0)), (1, 0)),  # type: ignore[arg-type]
    )
    route = TaskAssignment(
        TaxiId("t"),
        TaskId("k"),
        (),
        (),
        1e16,
        1e-5,
        -0.0,
        -math.inf,
        np.float32(2.0),  # type: ignore[arg-type]
        math.nan,
    )
    awkward_stats: dict[str, Any] = {
        "flag": np.bool_(True),
        "b": False,
        "n": np.int64(7),
        "f": np.float64(2.0),
        "g": np.float32(0.1),
        "nan": math.nan,
        "inf": np.float64(-np.inf),
        "s": "text",
        "step1_matches": np.int64(1),  # decide's count of the one Step 1 match (Decision.matches_by_step)
        "step2_matches": 0,
    }
    done = (
        Task(TaskId("k1"), 4, T0 - 60.0),
        Task(TaskId("k2"), 8, T0 - 30.5, "completed", T0 - 1.25, TaxiId("t"), "active"),
    )
    decision = Decision(
        epoch_id="é-1",
        time_s=T0,
        rider_matches=(match,),
        task_assignments=(route,),
        tasks_completed=done,
        task_updates=(),
        unmatched_rider_ids=(RiderId("u"),),
        expired_rider_ids=(RiderId("x"), RiderId("y")),
        visits=(),
        intervals_touched=(),
        stats=awkward_stats,
    )
    text = _check(_result(city, decision, snapshot, gamma_before=0.0, gamma_after=0.0), finite=False)
    assert '"trip_time_s":null' in text and '"nan"' not in text and '"flag":1' in text
    doc = epoch_doc(_result(city, decision, snapshot))
    assert doc["rider_matches"][0]["path"] == [int(v) for v in city.network.node_ids[[0, 1, 2]]]


def test_floats_of_every_magnitude_render_as_the_validated_models_do() -> None:
    """Finite doubles drawn from random bit patterns (every exponent, subnormals, whole numbers past 1e16)
    and the round numbers between: each written as the models write it."""
    city = grid_city(3, 300.0, cell_m=500.0)
    rng = np.random.default_rng(7)
    bits = rng.integers(0, 2**63, size=4000, dtype=np.uint64) | (rng.integers(0, 2, 4000, np.uint64) << 63)
    drawn = [float(x) for x in bits.view(np.float64) if math.isfinite(x)]
    drawn += [1e15, 1e16, 1e17, 1e21, 1e22, 2.0**53, 0.1, 1e-5, 1e-7, 5e-324, 123.456, -0.0, 3.0]
    fields = [tuple(drawn[i : i + 5]) for i in range(0, len(drawn) - 4, 5)]
    matches = tuple(
        RiderMatch(1, TaxiId(f"t{i}"), RiderId(f"r{i}"), a, b, c, d, e, (0,), ((0, 0),))
        for i, (a, b, c, d, e) in enumerate(fields)
    )
    decision = Decision(
        epoch_id="e",
        time_s=T0,
        rider_matches=matches,
        task_assignments=(),
        tasks_completed=(),
        task_updates=(),
        unmatched_rider_ids=(),
        expired_rider_ids=(),
        visits=(),
        intervals_touched=(),
        stats={"x": drawn[0], "y": drawn[1], "step1_matches": len(matches), "step2_matches": 0},
    )
    snapshot = Snapshot("e", T0, (), (Taxi(TaxiId("t"), 0, True, True),))
    _check(_result(city, decision, snapshot, solve_ms=drawn[2], gamma_before=drawn[3], gamma_after=drawn[4]))


def test_paths_read_their_own_networks_ids_under_threads() -> None:
    """Sixteen threads render paths of twelve networks at once, more networks than the id cache keeps: every
    path reads its own network's node ids."""
    cities = [grid_city(k, 300.0, cell_m=500.0) for k in range(2, 14)]

    def work(seed: int) -> int:
        rng = np.random.default_rng(seed)
        for _ in range(300):
            city = cities[int(rng.integers(len(cities)))]
            path = tuple(int(v) for v in rng.integers(city.network.n_nodes, size=5))
            assert _ext_paths(city, [path]) == [city.network.node_ids[list(path)].tolist()]
        return seed

    with ThreadPoolExecutor(16) as pool:
        assert sorted(pool.map(work, range(16))) == list(range(16))
