"""Simulation runs, built once and shared by the fleet-sizing worker and the research experiments.

A run is a pure function of its ``RunJob`` (spec, city bundle, recorded demand); ``Runner`` answers a batch
of jobs from its ``ResultCache`` (on disk, ``RunCache``, or in Redis, ``app.adapters.run_cache``) or by
running the rest on an ``Executor`` (this process, local processes, or a Dask cluster:
``app.runs.dask_executor``), reporting ``Progress`` as runs start and finish.
"""

from app.runs.cache import ResultCache, RunCache
from app.runs.executor import (
    Event,
    Executor,
    ExecutorName,
    ExecutorUnavailable,
    Finished,
    InlineExecutor,
    ProcessExecutor,
    Started,
)
from app.runs.factory import make_executor
from app.runs.result import RouteRecord, RunResult
from app.runs.runner import Progress, ProgressFn, RunBatch, RunFn, Runner
from app.runs.spec import CACHE_FORMAT, RunJob, RunSpec, TaskTemplate, demand_digest, tasks_digest
from app.runs.workload import Bundle, demand_for, open_bundle, run_job, simulate_spec, tasks_for

__all__ = [
    "CACHE_FORMAT",
    "RunSpec",
    "RunJob",
    "demand_digest",
    "TaskTemplate",
    "tasks_digest",
    "RunResult",
    "RouteRecord",
    "Bundle",
    "open_bundle",
    "demand_for",
    "tasks_for",
    "simulate_spec",
    "run_job",
    "Executor",
    "ExecutorName",
    "ExecutorUnavailable",
    "Event",
    "Started",
    "Finished",
    "InlineExecutor",
    "ProcessExecutor",
    "make_executor",
    "Progress",
    "ProgressFn",
    "RunBatch",
    "ResultCache",
    "RunCache",
    "Runner",
    "RunFn",
]
