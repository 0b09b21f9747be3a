"""A city bundle as bytes that travel to another machine, and the copies shipped to this process.

An executor whose workers may not share this disk (``DaskExecutor``) ships every bundle a batch reads: its
files (``BundleFiles``) go to each worker once, are written under the worker's own directory, and
``open_bundle`` reads that copy whenever a job names the bundle by its path on the submitting machine.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path

__all__ = ["BundleFiles", "install_shipped", "shipped_copy"]

_shipped: dict[str, Path] = {}  # source path on the submitting machine -> the copy in this process's disk
_lock = threading.Lock()


@dataclass(frozen=True, slots=True)
class BundleFiles:
    """Every regular file of a bundle directory (flat), read into memory, with their digest."""

    source: str
    files: tuple[tuple[str, bytes], ...]
    digest: str

    @classmethod
    def read(cls, directory: Path) -> BundleFiles:
        """The files of ``directory`` (an absolute path: jobs name bundles by it)."""
        if not directory.is_absolute():
            raise ValueError(f"bundle paths are absolute where jobs travel, got {directory}")
        files = tuple(
            (p.name, p.read_bytes()) for p in sorted(directory.iterdir(), key=lambda p: p.name) if p.is_file()
        )
        if not files:
            raise FileNotFoundError(f"no city bundle in {directory}")
        h = hashlib.sha256()
        for name, data in files:
            h.update(f"{name}\0{len(data)}\0".encode())
            h.update(data)
        return cls(str(directory), files, h.hexdigest())

    @property
    def size_bytes(self) -> int:
        """The bytes shipped."""
        return sum(len(data) for _, data in self.files)


def install_shipped(bundle: BundleFiles, root: Path) -> Path:
    """Write the bundle under ``root`` (once per digest: written to a temporary directory, then renamed) and
    make ``open_bundle`` read it for jobs that name ``bundle.source``; the copy's directory."""
    target = root / f"{Path(bundle.source).name}-{bundle.digest[:16]}"
    if not target.is_dir():
        tmp = root / f".{target.name}.{os.getpid()}.{threading.get_ident()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for name, data in bundle.files:
            (tmp / name).write_bytes(data)
        try:
            tmp.rename(target)
        except OSError:  # another process installed it meanwhile: same digest, same files
            shutil.rmtree(tmp, ignore_errors=True)
            if not target.is_dir():
                raise
    with _lock:
        _shipped[bundle.source] = target
    return target


def shipped_copy(directory: Path) -> Path:
    """Where this process reads the bundle a job names: its shipped copy, else the path itself."""
    with _lock:
        return _shipped.get(str(directory), directory)
