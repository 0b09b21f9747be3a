"""What the service process (``python -m app run``) does for its memory: glibc's mmap threshold fixed
(``app.entrypoints.server.tune_allocator``), and the kernels compiled in a child process
(``app.api.warmup.compile_apart``). Each check runs in a fresh process: both act on the whole process."""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from app.adapters.city_registry import BUNDLED_DIR, CityRegistry
from app.api.warmup import compile_apart

ROOT = Path(__file__).resolve().parents[2]

_HOLES = """
import ctypes, json, sys
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
if sys.argv[1] == "tuned":
    from app.entrypoints.server import tune_allocator
    assert tune_allocator()

def rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024

MB = 1 << 20
libc.free(libc.malloc(4 * MB))  # glibc raises its threshold past a freed mapped block of 4 MB
before = rss_mb()
big, small = [], []
for _ in range(100):  # 3 MB blocks, each followed by a 100 kB one that stays: freed blocks become holes
    p = libc.malloc(3 * MB)
    ctypes.memset(p, 1, 3 * MB)
    big.append(p)
    small.append(libc.malloc(100 << 10))
for p in big:
    libc.free(p)
print(json.dumps(rss_mb() - before))
"""


def _held_after_free(mode: str) -> float:
    out = subprocess.run(
        [sys.executable, "-c", _HOLES, mode], cwd=ROOT, capture_output=True, text=True, check=True
    )
    return float(json.loads(out.stdout))


def test_with_the_threshold_fixed_freed_blocks_leave_the_process() -> None:
    """300 MB of 3 MB blocks, freed between smaller blocks that stay: by default glibc (its threshold raised
    by an earlier free) serves them from the heap and keeps them resident; tuned, each was mapped on its
    own and is returned when freed."""
    assert _held_after_free("default") > 250.0
    assert _held_after_free("tuned") < 20.0


@pytest.mark.slow
def test_after_compiling_apart_the_warm_up_only_reads_the_cache() -> None:
    """In a fresh process: the kernels compiled in a child warming the smallest bundled city (Manhattan's
    network file is the smaller), then every bundled city warmed up here with no kernel compiled (every
    signature read from numba's cache)."""
    code = (
        "import json; from app.adapters.city_registry import CityRegistry; "
        "from app.api.warmup import compile_apart; "
        "from services.dispatch import warm_up; from tests.unit.test_warm_up import compiled_functions; "
        "reg = CityRegistry(); warmed = compile_apart(reg); [warm_up(reg.get(n)) for n in reg.names()]; "
        "fs = compiled_functions().values(); "
        "print(json.dumps([warmed, sum(sum(f.stats.cache_misses.values()) for f in fs), "
        "sum(sum(f.stats.cache_hits.values()) for f in fs)]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=900, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    warmed, misses, hits = json.loads(out.stdout.strip().splitlines()[-1])
    assert warmed == "manhattan"
    assert misses == 0 and hits > 0


def test_a_child_that_fails_is_logged_and_the_warm_up_goes_on(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A smallest bundle that cannot be read fails the child: logged, nothing raised, no city named."""
    broken = tmp_path / "tiny"
    shutil.copytree(BUNDLED_DIR / "manhattan", broken, ignore=shutil.ignore_patterns("*.csv", "*.gz"))
    (broken / "network.npz").write_bytes(b"not a network")
    meta = json.loads((broken / "city.json").read_text())
    meta["name"] = "tiny"
    (broken / "city.json").write_text(json.dumps(meta))
    with caplog.at_level(logging.WARNING, logger="app.api.warmup"):
        assert compile_apart(CityRegistry(user_dir=tmp_path)) is None
    assert "compiling the kernels in a child process failed" in caplog.text
