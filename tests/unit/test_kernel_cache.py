"""The compiled kernels' cache is keyed on every source of ``services``: a change to any module (a helper
another module's kernel inlines, say) sends every kernel to a fresh cache directory, so no kernel runs code
compiled from sources that are no longer there."""

from __future__ import annotations

import shutil
from pathlib import Path

import numba

from services.kernel.jit import SERVICES, cache_dir


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
