"""Give the heap's free pages back to the system after each job (glibc's ``malloc_trim``).

A job allocates hundreds of MB in short-lived arrays (the photo, its segmentation, features, matches) from
several threads. glibc keeps what they free inside its per-thread arenas, so a worker's resident memory
followed the largest mix of jobs it had seen rather than what it holds. Measured in a 25-minute soak
(``benchmarks/bench_soak.py``, 2 workers, a ``mallinfo2`` sampler): each worker's arenas held 250 to 370 MB of
which only 83 to 111 MB was in use; the free part rose and fell by 50 MB from job to job and drifted up. After
:func:`release_free_heap` the resident size tracks the memory in use (the caches of
:mod:`workers.reference_store` and the loaded maps). Elsewhere than glibc (musl, macOS) it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from collections.abc import Callable
from functools import lru_cache


@lru_cache(maxsize=1)
def _malloc_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    try:
        trim = ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):
        trim = None
    if trim is not None:
        trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Return the heap's whole free pages (every arena) to the system; False where the C library cannot."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
