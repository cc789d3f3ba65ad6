"""After each job: collect its garbage, keep the collector off what outlives it, give free pages back.

A job allocates hundreds of MB in short-lived arrays (the photo, its segmentation, features, matches) from
several threads. glibc keeps what they free inside its per-thread arenas, so a worker's resident memory
followed the largest mix of jobs it had seen rather than what it holds. Measured in a 25-minute soak
(``benchmarks/bench_soak.py``, 2 workers, a ``mallinfo2`` sampler): each worker's arenas held 250 to 370 MB of
which only 83 to 111 MB was in use; the free part rose and fell by 50 MB from job to job and drifted up. After
:func:`release_free_heap` the resident size tracks the memory in use (the caches of
:mod:`workers.reference_store` and the loaded maps). Elsewhere than glibc (musl, macOS) it does nothing.

Python's collector: a worker holds 100 k+ long-lived objects (the imported modules, the loaded maps, networks,
vocabularies) and each full collection walks all of them (65 ms on the shared machine, measured with
``gc.collect()`` after importing the handlers). :func:`settle_heap` (before the first job and after each)
collects the job's cyclic garbage, then ``gc.freeze()`` moves every object that survived into the permanent
generation, which the collector no longer walks; a collection during the next job walks only that job's objects
(measured in process on world h1, labelling its 60 references: the collector's CPU 0.20 s of 34.2 s unfrozen, 0.07 s
frozen; a settle costs 0.3 to 1.5 ms). Frozen objects are still freed by reference counting; only a reference cycle
among them would stay. The long-lived objects of a worker hold none (checked: a loaded map, its places and the
vocabulary, dropped, leave nothing for the collector), so no full collection is run again: it would also write to
every frozen object, unsharing the pages a forked pool's children share with their parent
(:mod:`workers.pool`, which freezes its heap before it forks).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
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


TRIM_EVERY_JOBS = 16
"""A worker busy this many jobs in a row trims its heap anyway (:class:`HeapTrimmer`)."""


def settle_heap(trim: bool = True) -> bool:
    """Collect the garbage (cycles), freeze what survives (``gc.freeze``), and trim the heap unless ``trim`` is False.

    Returns whether the heap was trimmed (:func:`release_free_heap`). The worker settles before its first job and
    after each; it trims when :class:`HeapTrimmer` says.
    """
    gc.collect()
    gc.freeze()
    return release_free_heap() if trim else False


class HeapTrimmer:
    """When a worker returns its heap's free pages (``GEOLOC_WORKER_TRIM_IDLE_S``).

    Once idle ``idle_s`` after a job, or after every :data:`TRIM_EVERY_JOBS` jobs in a row; after every job when
    ``idle_s`` is 0.

    Trimming after every job kept the workers' memory flat in the hour's soak, but the next job then faults its
    pages back in: 25 ms of a query's 565 ms of worker CPU and 30 ms of its latency (``bench_service.py`` on the
    Helsinki world, the same run with and without). Back-to-back jobs reuse the free pages instead.
    """

    def __init__(self, idle_s: float) -> None:
        """idle_s: seconds idle after a job before trimming (0: trim after every job)."""
        self.idle_s = idle_s
        self.untrimmed_jobs = 0
        self.last_job_end = 0.0

    def job_done(self, now: float) -> None:
        """A job ended at ``now`` (monotonic seconds): settle the heap, trimming it when it is time."""
        self.untrimmed_jobs += 1
        self.last_job_end = now
        trim = self.idle_s <= 0 or self.untrimmed_jobs >= TRIM_EVERY_JOBS
        if settle_heap(trim=trim):
            self.untrimmed_jobs = 0

    def idle(self, now: float) -> bool:
        """The worker found no job at ``now``: trim once it has been idle long enough; True if it trimmed."""
        if self.untrimmed_jobs == 0 or now - self.last_job_end < self.idle_s:
            return False
        self.untrimmed_jobs = 0
        return release_free_heap()
