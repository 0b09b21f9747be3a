"""Another checkout's ``decide`` beside this one's, on the same epochs: the epoch benchmark's same-run ratio to
the previous code (``python -m bench.bench_epoch --baseline DIR``, DIR a checkout of it, e.g. ``git worktree
add ../base main``).

The other checkout runs in a process of its own (its ``services`` first on the path), started once per
scenario: it receives the city, warms it up as the service does, then takes each epoch's inputs (counts,
snapshot, tasks, threads) and returns its decision and the time ``decide`` took. Inputs and decisions cross
as pickles of the core's types, which both checkouts must share.

    python bench/baseline.py      # (run by ``Baseline``, with PYTHONPATH set to the other checkout)
"""

from __future__ import annotations

import gc
import os
import pickle
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

__all__ = ["Baseline"]


class Baseline:
    """The ``decide`` of the checkout at ``root``, in a child process, for one city."""

    def __init__(self, root: Path, city: Any) -> None:
        env = {**os.environ, "PYTHONPATH": str(Path(root).resolve())}
        self._proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve())],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            cwd=root,
            env=env,
        )
        self.origin = str(self._ask(("city", city)))

    def _ask(self, message: tuple[Any, ...]) -> Any:
        proc = self._proc
        assert proc.stdin is not None and proc.stdout is not None
        pickle.dump(message, proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        proc.stdin.flush()
        try:
            return pickle.load(proc.stdout)
        except EOFError:
            raise RuntimeError(f"the baseline process exited ({proc.wait()})") from None

    def decide(self, view: Any, snap: Any, tasks: Sequence[Any], workers: int) -> tuple[float, Any]:
        """The other checkout's decision on these inputs and the seconds its ``decide`` took."""
        took, d = self._ask(("decide", view, snap, list(tasks), workers))
        return float(took), d

    def close(self) -> None:
        proc = self._proc
        if proc.stdin is not None:
            proc.stdin.close()
        proc.wait(timeout=60)


def as_the_server() -> None:
    """The API process's garbage collector (``app.api.warmup``): its thresholds, and what start-up built
    (the city, the compiled kernels' objects) frozen out of the collector's reach, so that a timed
    ``decide`` pays the collections the server pays, not the full scans of a default process."""
    from app.api.warmup import GC_THRESHOLD

    # written out rather than calling the server's start-up (``app.api.warmup.warm``, which also loads every
    # served city): the previous code's process runs whatever app the checkout it is given has
    gc.set_threshold(*GC_THRESHOLD)
    gc.collect()
    gc.freeze()


def _serve(inp: IO[bytes], out: IO[bytes]) -> None:
    import services
    from services.dispatch import decide, warm_up

    city: Any = None
    while True:
        try:
            message = pickle.load(inp)
        except EOFError:
            return
        if message[0] == "city":
            city = message[1]
            warm_up(city)
            as_the_server()
            reply: Any = str(Path(services.__file__).resolve().parents[1])
        else:
            _, view, snap, tasks, workers = message
            started = time.perf_counter()
            d = decide(city, view, snap, tasks, workers=workers)
            reply = (time.perf_counter() - started, d)
        pickle.dump(reply, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()


if __name__ == "__main__":
    sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
    _serve(sys.stdin.buffer, sys.stdout.buffer)
