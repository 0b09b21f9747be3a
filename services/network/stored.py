"""Structures built once per network (the contraction hierarchy, the landmark table) kept on disk, so that a
restart reads them instead of building them again (on a metropolitan network the hierarchy takes 15-20 s
to build and a fraction of a second to read).

A structure is stored under a key made of its kind and a digest of everything it is built from (the
network's arrays, and its parameters), in a directory beside the compiled kernels (``kernel.jit``'s cache
directory, named after a digest of the sources: other code, other directory, and ``jit.prune_stale``
removes it with the kernels). A file is written under a temporary name and renamed, so a reader never sees
half of one; a file that cannot be read, or whose arrays are not what the caller expects, is built again.
Where nothing can be written, the structure is simply built every time.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import threading
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["Arrays", "kept", "shaped", "directory"]

Arrays = dict[str, NDArray[np.generic]]
"""A stored structure: its arrays by name."""

log = logging.getLogger(__name__)


def directory() -> Path:
    """Where the structures of this code are stored: ``stored/`` in the compiled kernels' cache directory."""
    return Path(numba.config.CACHE_DIR) / "stored"  # type: ignore[attr-defined]


def digest(*parts: NDArray[np.generic] | int | str) -> str:
    """A digest of ``parts`` (arrays by dtype, shape and bytes; numbers and text by value)."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.data)
        else:
            h.update(repr(p).encode())
        h.update(b"|")
    return h.hexdigest()[:32]


def _path(kind: str, key: str, root: Path | None) -> Path:
    return (root or directory()) / f"{kind}-{key}.npz"


def load(kind: str, key: str, root: Path | None = None) -> Arrays | None:
    """The arrays stored as ``kind`` under ``key`` (None: none stored, or the file cannot be read)."""
    path = _path(kind, key, root)
    try:
        with np.load(path, allow_pickle=False) as z:
            return {name: z[name] for name in z.files}
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        log.warning("stored %s unreadable, building it again: %s", path.name, exc)
        return None


def save(kind: str, key: str, arrays: Arrays, root: Path | None = None) -> bool:
    """Store ``arrays`` as ``kind`` under ``key``; False when it cannot be written (nothing changes)."""
    path = _path(kind, key, root)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
        return True
    except OSError as exc:
        log.info("could not store %s (%s): it will be built again next time", path.name, exc)
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        return False


def shaped(arrays: Arrays, spec: Mapping[str, tuple[type, tuple[int | None, ...]]]) -> bool:
    """Whether ``arrays`` holds exactly the arrays ``spec`` names, each of its dtype and shape (a None
    dimension: any length)."""
    if set(arrays) != set(spec):
        return False
    for name, (dtype, shape) in spec.items():
        a = arrays[name]
        if a.dtype != dtype or len(a.shape) != len(shape):
            return False
        if any(want is not None and got != want for got, want in zip(a.shape, shape, strict=True)):
            return False
    return True


def kept(
    kind: str,
    parts: tuple[NDArray[np.generic] | int | str, ...],
    build: Callable[[], Arrays],
    fits: Callable[[Arrays], bool],
    root: Path | None = None,
) -> Arrays:
    """The arrays of ``kind`` built from ``parts`` (everything they depend on): read back when they were
    stored before (under ``root``, else ``directory()``) and ``fits`` them, else ``build()``, stored, and
    returned."""
    key = digest(*parts)
    got = load(kind, key, root)
    if got is not None and fits(got):
        return got
    arrays = build()
    save(kind, key, arrays, root)
    return arrays
