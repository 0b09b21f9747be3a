"""Run many specs over worker processes, with a progress bar, resumably.

Each finished run is written to ``<out>/runs/<key>.json`` (atomically: a temporary file renamed), so an
interrupted experiment picks up where it stopped and finished runs are never redone.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from tqdm import tqdm

from app.experiment.workload import RunSpec, run_result

__all__ = ["RunFailed", "run_all", "load_results"]


class RunFailed(RuntimeError):
    """Some runs raised; the others are saved and a rerun only redoes the failed ones."""


def _path(out_dir: Path, spec: RunSpec) -> Path:
    return out_dir / "runs" / f"{spec.key}.json"


def _save(out_dir: Path, result: dict[str, Any]) -> None:
    path = out_dir / "runs" / f"{result['key']}.json"
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(result, separators=(",", ":")))
    tmp.replace(path)


def _cost(spec: RunSpec) -> float:
    """Rough relative cost, to start the long runs first (better packing over the workers)."""
    return (spec.n1 * (4.0 if spec.active and not spec.wait_only else 1.0)) + spec.n0 * 0.2


def run_all(
    specs: Sequence[RunSpec], out_dir: Path, *, jobs: int = 2, desc: str = "runs", quiet: bool = False
) -> dict[str, dict[str, Any]]:
    """Run every spec not already saved under ``out_dir``; return all results by key."""
    (out_dir / "runs").mkdir(parents=True, exist_ok=True)
    unique = list({s.key: s for s in specs}.values())
    todo = sorted((s for s in unique if not _path(out_dir, s).exists()), key=_cost, reverse=True)
    failed: list[str] = []
    with tqdm(
        total=len(unique),
        initial=len(unique) - len(todo),
        desc=desc,
        unit="run",
        disable=quiet,
        file=sys.stderr,
        dynamic_ncols=True,
    ) as bar:
        if jobs <= 1:
            for spec in todo:
                _save(out_dir, run_result(spec))
                bar.update()
        elif todo:
            ctx = multiprocessing.get_context("forkserver")
            with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
                futures: dict[Future[dict[str, Any]], RunSpec] = {pool.submit(run_result, s): s for s in todo}
                for fut in as_completed(futures):
                    try:
                        _save(out_dir, fut.result())
                    except Exception as exc:  # noqa: BLE001 - reported below, the other runs go on
                        failed.append(f"{futures[fut].key}: {exc!r}")
                    bar.update()
    if failed:
        raise RunFailed(f"{len(failed)} run(s) failed (rerun to retry only those):\n" + "\n".join(failed))
    return load_results(unique, out_dir)


def load_results(specs: Sequence[RunSpec], out_dir: Path) -> dict[str, dict[str, Any]]:
    """The saved results of ``specs`` (every one must exist)."""
    out = {}
    for s in specs:
        out[s.key] = json.loads(_path(out_dir, s).read_text())
    return out
