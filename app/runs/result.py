"""The result of one run: its KPIs (``services.sim.kpi.RunKpis``) with the spec, the demand manifest and the
Step 3 routes when asked for, as one JSON document (NaN written as ``null``) that the cache keeps."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from typing import Any, TypeVar

from app.runs.spec import RunSpec
from services.sim.kpi import HourKpis, RunKpis, TaskOutcome

__all__ = ["RunResult", "RouteRecord"]

_T = TypeVar("_T")


@dataclass(frozen=True, slots=True)
class RouteRecord:
    """One Step 3 route of a run: when it was assigned, to whom, for which task, and its nodes."""

    time_s: float
    taxi_id: str
    task_id: str
    path: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class RunResult:
    """One finished run."""

    key: str
    spec: RunSpec
    demand: dict[str, Any]  # the demand set's manifest (generator, version, seed, date, ...)
    kpis: RunKpis
    n_unposted: int  # requests after the last epoch (not part of the run)
    elapsed_s: float  # the run's wall time (the bundle's opening, once per process, not included)
    routes: tuple[RouteRecord, ...] | None = None  # with ``spec.keep_routes``
    cpu_s: float | None = None  # the run's processor time in its process (None: not measured)

    @property
    def date(self) -> str:
        """The local date of the simulated day."""
        return str(self.demand["date"])

    @property
    def n_requests(self) -> int:
        """Every request of the day, posted or not."""
        return self.kpis.n_requests + self.n_unposted

    def to_json(self) -> str:
        """The cached document (NaN as ``null``)."""
        doc = {
            "key": self.key,
            "spec": dataclasses.asdict(self.spec),
            "demand": self.demand,
            "kpis": _nan_to_null(dataclasses.asdict(self.kpis)),
            "n_unposted": self.n_unposted,
            "elapsed_s": self.elapsed_s,
            "routes": None if self.routes is None else [dataclasses.asdict(r) for r in self.routes],
            "cpu_s": self.cpu_s,
        }
        return json.dumps(doc, separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_json(cls, text: str) -> RunResult:
        """Inverse of ``to_json`` (raises ``ValueError``, ``KeyError`` or ``TypeError`` on a bad document)."""
        d = json.loads(text)
        k = dict(d["kpis"])
        hours = tuple(_typed(HourKpis, h) for h in k.pop("hours"))
        tasks = tuple(_typed(TaskOutcome, t) for t in k.pop("tasks"))
        routes = d.get("routes")
        cpu = d.get("cpu_s")
        return cls(
            key=str(d["key"]),
            spec=RunSpec(**d["spec"]),
            demand=dict(d["demand"]),
            kpis=_typed(RunKpis, {**k, "hours": hours, "tasks": tasks}),
            n_unposted=int(d["n_unposted"]),
            elapsed_s=float(d["elapsed_s"]),
            routes=None
            if routes is None
            else tuple(
                RouteRecord(float(r["time_s"]), r["taxi_id"], r["task_id"], tuple(r["path"])) for r in routes
            ),
            cpu_s=None if cpu is None else float(cpu),
        )


def _nan_to_null(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _nan_to_null(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_nan_to_null(v) for v in value]
    return value


def _typed(kind: type[_T], doc: dict[str, Any]) -> _T:
    """A dataclass from its JSON fields: ``null`` back to NaN where the field is a plain float."""
    names = {f.name: f.type for f in dataclasses.fields(kind)}  # type: ignore[arg-type]
    unknown = set(doc) - set(names)
    if unknown:
        raise KeyError(f"{kind.__name__} has no fields {sorted(unknown)}")
    values = {n: (math.nan if v is None and names[n] == "float" else v) for n, v in doc.items()}
    return kind(**values)
