"""docs/PERFORMANCE.md is assembled from sections, one per benchmark, each between markers.

A benchmark replaces only its own section (``<!-- bench:NAME -->`` ... ``<!-- /bench:NAME -->``), so
running one benchmark never erases another's numbers, nor the hand-written text between sections.
"""

from __future__ import annotations

import datetime as dt
import os
import platform
import re
from pathlib import Path

import numpy as np
import scipy

ROOT = Path(__file__).resolve().parents[1]
PERFORMANCE = ROOT / "docs" / "PERFORMANCE.md"
ORDER = (
    "epoch",
    "epoch-redis",
    "search",
    "sim",
    "experiment",
    "dro",
    "worker",
    "fleet-service",
    "fleet-own-city",
    "cluster",
    "fleet-metro",
    "hardening",
)  # section order in the document
_HEAD = "# Performance\n\nEach section below is written by one benchmark (`make bench` runs them all).\n"


def machine() -> str:
    """CPU, cores, OS and the numeric stack, for the record."""
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import numba

    return (
        f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}; Python "
        f"{platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, numba {numba.__version__}"
    )


def stamp(command: str, where: str | None = None) -> str:
    """The 'measured when, how, where' line that opens every section (``where``: the machine the numbers
    were measured on, when not this one)."""
    return f"Measured {dt.date.today().isoformat()} with `{command}`. Machine: {where or machine()}."


def write_section(name: str, markdown: str, path: Path = PERFORMANCE) -> Path:
    """Replace (or add) section ``name`` of the performance document with ``markdown``; everything else in the
    document, other sections and hand-written text between them alike, stays as it is. A new section goes
    before the first section that follows it in ``ORDER``, else at the end."""
    text = path.read_text() if path.exists() else _HEAD
    block = f"<!-- bench:{name} -->\n{markdown.rstrip(chr(10))}\n<!-- /bench:{name} -->\n"
    span = re.search(rf"<!-- bench:{name} -->\n.*?<!-- /bench:{name} -->\n?", text, flags=re.S)
    if span is not None:
        text = text[: span.start()] + block + text[span.end() :]
    else:
        later = ORDER[ORDER.index(name) + 1 :] if name in ORDER else ()
        starts = [m.start() for n in later if (m := re.search(rf"<!-- bench:{n} -->\n", text))]
        at = min(starts, default=len(text))
        before, after = text[:at].rstrip("\n") + "\n\n", text[at:]
        text = before + block + ("\n" + after if after else "")
    path.write_text(text)
    return path
