"""The one way the core compiles its inner loops: numba's ``njit`` with an on-disk cache and the GIL
released (the searches of an epoch run on several threads), typed so that mypy checks the callers against
the functions' own signatures."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

__all__ = ["compiled", "compiled_inline"]

_F = TypeVar("_F", bound=Callable[..., Any])


def compiled(fn: _F) -> _F:
    """Compile ``fn`` (nopython, cached on disk, without the GIL)."""
    return cast(_F, numba.njit(cache=True, nogil=True)(fn))


def compiled_inline(fn: _F) -> _F:
    """``compiled``, and inlined into its compiled callers (small helpers of the innermost loops)."""
    return cast(_F, numba.njit(cache=True, nogil=True, inline="always")(fn))
