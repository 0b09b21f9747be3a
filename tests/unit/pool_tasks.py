"""Functions the executor tests send to pool processes: a light module the processes import by name (the
test module itself imports the whole simulation, which would make every pool start slow)."""

from __future__ import annotations

import os
from typing import Any


def square_unless_3(x: int) -> int:
    """``x * x``; 3 raises."""
    if x == 3:
        raise ValueError("three")
    return x * x


def exit_on_2(x: int) -> int:
    """``x``; for 2 the process dies without a word, as a killed one would."""
    if x == 2:
        os._exit(7)
    return x


def count_until_stopped(directory: str) -> int:
    """Count up, writing the count to ``directory/count`` every few milliseconds, until the file
    ``directory/stop`` appears; the last count."""
    import pathlib
    import time

    here = pathlib.Path(directory)
    n = 0
    while not (here / "stop").exists():
        n += 1
        (here / "count.tmp").write_text(str(n))
        os.replace(here / "count.tmp", here / "count")
        time.sleep(0.005)
    return n


def executor_then_die(directory: str) -> None:
    """In a process of its own: start a run on a ``ProcessExecutor``, write the run's pid to
    ``directory/pid`` once it counts (the pool's forkserver's to ``directory/forkserver``), then end
    abruptly (as a killed service would)."""
    import pathlib
    import threading
    import time

    from app.runs.executor import ProcessExecutor, Started

    here = pathlib.Path(directory)
    executor = ProcessExecutor(1)

    def run() -> None:
        for event in executor.map_unordered(count_until_stopped, [directory]):
            if isinstance(event, Started):
                (here / "pid.tmp").write_text(str(event.pid))
                os.replace(here / "pid.tmp", here / "pid")

    threading.Thread(target=run, daemon=True).start()
    while not ((here / "pid").exists() and (here / "count").exists()):
        time.sleep(0.01)
    from multiprocessing import forkserver

    server: Any = forkserver._forkserver  # the running forkserver, for the test to end it
    (here / "forkserver").write_text(str(server._forkserver_pid))
    os._exit(0)


def pid_and_square(x: int) -> tuple[int, int]:
    """The process it ran in, and ``square_unless_3(x)``."""
    return os.getpid(), square_unless_3(x)
