"""The one way the core compiles its inner loops: numba's ``njit`` with an on-disk cache and the GIL
released (the searches of an epoch run on several threads), typed so that mypy checks the callers against
the functions' own signatures.

numba checks a cached function against its own file only, so a kernel that inlines a helper from another
module would keep its old compiled code after that module changed. The cache therefore lives in a directory
named after a digest of every source file of ``services`` (``cache_dir``): other code, other directory.
The directories of other sources are never read again by this code; ``prune_stale`` removes those left
untouched for a while (the service does at start-up), so that each upgrade does not leave its kernels on disk.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba

__all__ = ["cache_dir", "prune_stale", "STALE_AFTER_S", "compiled", "compiled_inline"]

SERVICES = Path(__file__).resolve().parents[1]


def cache_dir(root: Path = SERVICES, base: str = "") -> str:
    """Where the compiled kernels of the sources below ``root`` are cached: in ``base`` (else
    ``root/__pycache__/numba``, else ``~/.cache/sensedispatch/numba`` when ``root`` is read-only), the
    directory named by a digest of the sources' names and contents."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    base = base or (
        str(root / "__pycache__" / "numba")
        if os.access(root, os.W_OK)
        else str(Path.home() / ".cache" / "sensedispatch" / "numba")
    )
    return os.path.join(base, digest.hexdigest()[:16])


STALE_AFTER_S = 86_400.0
"""A cache directory of other sources untouched (no file written) for this long is removed by ``prune_stale``:
a process of an older checkout still running has its kernels in memory and only recompiles what it loads
anew (a simulation process starting, say)."""


def prune_stale(current: str, older_than_s: float = STALE_AFTER_S) -> list[tuple[str, int]]:
    """Remove the cache directories beside ``current`` (``cache_dir``'s) that hold other sources' kernels
    and have had no file written for ``older_than_s``; the removed directories and their bytes."""
    base = Path(current).parent
    cutoff = time.time() - older_than_s
    removed: list[tuple[str, int]] = []
    try:
        siblings = [d for d in base.iterdir() if d.is_dir() and d.name != Path(current).name]
    except OSError:
        return removed
    for d in siblings:
        try:
            files = [f.stat() for f in d.rglob("*") if f.is_file()]
            if max((f.st_mtime for f in files), default=d.stat().st_mtime) > cutoff:
                continue
            shutil.rmtree(d)
        except OSError:  # gone meanwhile, or not ours to remove: left as it is
            continue
        removed.append((str(d), sum(f.st_size for f in files)))
    return removed


# numba read $NUMBA_CACHE_DIR at its import; its config is read again as each kernel below is decorated
numba.config.CACHE_DIR = cache_dir(SERVICES, numba.config.CACHE_DIR)  # type: ignore[attr-defined]

_F = TypeVar("_F", bound=Callable[..., Any])


def compiled(fn: _F) -> _F:
    """Compile ``fn`` (nopython, cached on disk, without the GIL)."""
    return cast(_F, numba.njit(cache=True, nogil=True)(fn))


def compiled_inline(fn: _F) -> _F:
    """``compiled``, and inlined into its compiled callers (small helpers of the innermost loops)."""
    return cast(_F, numba.njit(cache=True, nogil=True, inline="always")(fn))
