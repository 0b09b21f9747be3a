"""Compiled kernels and threads, the machinery every search and evaluation runs on (no paper section).

* ``jit``: the one typed numba ``njit`` (on-disk cache, no Python fallback).
* ``parallel``: a thread map with the number of threads passed in.
"""

from services.kernel.jit import compiled, compiled_inline
from services.kernel.parallel import default_workers, parallel_map

__all__ = ["compiled", "compiled_inline", "parallel_map", "default_workers"]
