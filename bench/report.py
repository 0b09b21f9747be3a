"""docs/PERFORMANCE.md is assembled from sections, one per benchmark, each between markers.

A benchmark replaces only its own section (``<!-- bench:NAME -->`` ... ``<!-- /bench:NAME -->``), so
running one benchmark never erases another's numbers.
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
    "sim",
    "experiment",
    "dro",
    "worker",
    "cluster",
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


def stamp(command: str) -> str:
    """The 'measured when, how, where' line that opens every section."""
    return f"Measured {dt.date.today().isoformat()} with `{command}`. Machine: {machine()}."


def _sections(text: str) -> dict[str, str]:
    found = re.findall(r"<!-- bench:(\w+) -->\n(.*?)<!-- /bench:\1 -->\n?", text, flags=re.S)
    return {name: body for name, body in found}


def write_section(name: str, markdown: str, path: Path = PERFORMANCE) -> Path:
    """Replace (or add) section ``name`` of the performance document with ``markdown``."""
    sections = _sections(path.read_text()) if path.exists() else {}
    sections[name] = markdown.rstrip("\n") + "\n"
    names = [n for n in ORDER if n in sections] + sorted(n for n in sections if n not in ORDER)
    parts = [_HEAD]
    for n in names:
        parts.append(f"\n<!-- bench:{n} -->\n{sections[n]}<!-- /bench:{n} -->\n")
    path.write_text("".join(parts))
    return path
