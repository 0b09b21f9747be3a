"""Functions the cluster tests send to Dask workers: they live in a module the workers import by its
package name (pytest imports test modules under their bare file name, which a worker cannot)."""

from __future__ import annotations

from app.runs import RunJob, open_bundle


def where_opened(job: RunJob) -> str:
    """Where the worker reads the job's bundle from."""
    return str(open_bundle(job.bundle).directory)
