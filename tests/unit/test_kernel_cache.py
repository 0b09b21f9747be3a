"""The compiled kernels' cache is keyed on every source of ``services``: a change to any module (a helper
another module's kernel inlines, say) sends every kernel to a fresh cache directory, so no kernel runs code
compiled from sources that are no longer there."""

from __future__ import annotations

import logging
import os
import shutil
import time
from pathlib import Path

import numba
import pytest

from services.kernel.jit import SERVICES, STALE_AFTER_S, cache_dir, prune_stale


def _tree(tmp_path: Path) -> Path:
    root = tmp_path / "services"
    (root / "network").mkdir(parents=True)
    (root / "__init__.py").write_text('"""core"""\n')
    (root / "network" / "heaps.py").write_text("def less(a, b):\n    return a < b\n")
    (root / "network" / "astar.py").write_text("from .heaps import less\n")
    return root


def test_the_kernels_are_cached_under_the_digest_of_these_sources() -> None:
    kept = numba.config.CACHE_DIR  # type: ignore[attr-defined]
    assert Path(kept).name == Path(cache_dir(SERVICES)).name  # in $NUMBA_CACHE_DIR when set


def test_any_change_to_any_source_moves_the_cache(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    first = cache_dir(root)
    assert Path(first).parent == root / "__pycache__" / "numba"
    assert cache_dir(root) == first  # the same sources: the same directory
    (root / "network" / "heaps.py").write_text("def less(a, b):\n    return a <= b\n")
    changed = cache_dir(root)
    assert changed != first
    (root / "network" / "heaps.py").rename(root / "network" / "queues.py")  # the same text, moved
    assert cache_dir(root) not in (first, changed)
    shutil.rmtree(root / "network")
    (root / "network").mkdir()
    (root / "network" / "heaps.py").write_text("def less(a, b):\n    return a < b\n")
    (root / "network" / "astar.py").write_text("from .heaps import less\n")
    assert cache_dir(root) == first  # back to the first sources: back to their cache


def test_numba_cache_dir_is_the_base_when_set(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    assert Path(cache_dir(root, str(tmp_path / "elsewhere"))).parent == tmp_path / "elsewhere"


def _kernels(directory: Path, age_s: float) -> None:
    """A cache directory holding one kernel file written ``age_s`` ago."""
    (directory / "network").mkdir(parents=True)
    f = directory / "network" / "heaps.less-1.py311.nbi"
    f.write_bytes(b"x" * 1000)
    then = time.time() - age_s
    os.utime(f, (then, then))


def test_other_sources_caches_untouched_for_a_day_are_removed_and_no_other(tmp_path: Path) -> None:
    base = tmp_path / "numba"
    current = base / "aaaaaaaaaaaaaaaa"
    _kernels(current, 10 * STALE_AFTER_S)  # the current sources' kernels, however old: kept
    _kernels(base / "bbbbbbbbbbbbbbbb", 2 * STALE_AFTER_S)  # an earlier version's: removed
    _kernels(base / "cccccccccccccccc", 60.0)  # written a minute ago (a process of it may run): kept
    (base / "notes.txt").write_text("a file beside the directories is not a cache: kept")
    removed = prune_stale(str(current))
    assert removed == [(str(base / "bbbbbbbbbbbbbbbb"), 1000)]
    assert sorted(p.name for p in base.iterdir()) == ["aaaaaaaaaaaaaaaa", "cccccccccccccccc", "notes.txt"]
    assert prune_stale(str(current)) == []  # nothing left to remove
    assert prune_stale(str(tmp_path / "absent" / "aaaaaaaaaaaaaaaa")) == []  # no base: nothing to do


def test_the_service_start_up_prunes_beside_its_own_cache_and_logs_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from app.api.warmup import _prune_kernel_caches

    base = tmp_path / "numba"
    _kernels(base / "aaaaaaaaaaaaaaaa", 0.0)
    _kernels(base / "bbbbbbbbbbbbbbbb", 2 * STALE_AFTER_S)
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(base / "aaaaaaaaaaaaaaaa"))
    with caplog.at_level(logging.INFO, logger="app.api.warmup"):
        _prune_kernel_caches()
    assert [p.name for p in base.iterdir()] == ["aaaaaaaaaaaaaaaa"]
    assert "removed 1 stale kernel cache directories (0.0 MB)" in caplog.text
