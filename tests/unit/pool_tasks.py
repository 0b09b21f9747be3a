"""Functions the executor tests send to pool processes: a light module the processes import by name (the
test module itself imports the whole simulation, which would make every pool start slow)."""

from __future__ import annotations

import os


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
