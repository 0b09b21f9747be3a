"""The executor a configuration names (``SD_WORKER_EXECUTOR``): this process or local processes
(``app.runs.executor``), or a Dask cluster (``app.runs.dask_executor``, imported only when named:
``distributed`` is an optional extra)."""

from __future__ import annotations

from app.runs.executor import Executor, ExecutorName, InlineExecutor, ProcessExecutor

__all__ = ["make_executor"]


def make_executor(
    workers: int,
    name: ExecutorName = "local",
    *,
    scheduler: str | None = None,
    timeout_s: float = 10.0,
    nice: int = 0,
    in_process: bool = True,
) -> Executor:
    """The executor a configuration names: ``local`` runs in this process with one worker (unless
    ``in_process`` is False: then on one local process), else on ``workers`` local processes started with
    ``nice``; ``dask`` on the Dask cluster whose scheduler is at ``scheduler`` (the connection is made by
    the first batch that has something to run)."""
    if name == "dask":
        if not scheduler:
            raise ValueError("the dask executor needs the scheduler's address (SD_DASK_SCHEDULER)")
        from app.runs.dask_executor import DaskExecutor

        return DaskExecutor(scheduler, timeout_s=timeout_s)
    if name != "local":
        raise ValueError(f"unknown executor {name!r}")
    if workers == 1 and in_process:
        return InlineExecutor()
    return ProcessExecutor(workers, nice=nice)
