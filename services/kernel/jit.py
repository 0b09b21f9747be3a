"""The one way the core compiles its inner loops: numba's ``njit`` with an on-disk cache and the GIL
released (the searches of an epoch run on several threads), typed so that mypy checks the callers against
the functions' own signatures.

numba checks a cached function against its own file only, so a kernel that inlines a helper from another
module would keep its old compiled code after that module changed. The cache therefore lives in a directory
named after a digest of every source file of ``services`` (``cache_dir``): other code, other directory.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba

__all__ = ["cache_dir", "compiled", "compiled_inline"]

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


# numba read $NUMBA_CACHE_DIR at its import; its config is read again as each kernel below is decorated
numba.config.CACHE_DIR = cache_dir(SERVICES, numba.config.CACHE_DIR)  # type: ignore[attr-defined]

_F = TypeVar("_F", bound=Callable[..., Any])


def compiled(fn: _F) -> _F:
    """Compile ``fn`` (nopython, cached on disk, without the GIL)."""
    return cast(_F, numba.njit(cache=True, nogil=True)(fn))


def compiled_inline(fn: _F) -> _F:
    """``compiled``, and inlined into its compiled callers (small helpers of the innermost loops)."""
    return cast(_F, numba.njit(cache=True, nogil=True, inline="always")(fn))
