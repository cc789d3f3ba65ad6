"""The worker gives freed heap pages back after a job (glibc): resident memory follows what is in use."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from workers.memory import release_free_heap


def _resident_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError("no VmRSS")


def _fragment_heap(kept: list[np.ndarray]) -> None:
    """What a job does: many mid-sized arrays from a thread, freed, with a few small ones outliving it."""
    np.ones(8_000_000)  # freeing a large mmapped block raises glibc's mmap threshold (as a job's image does)
    rng = np.random.default_rng(0)
    working = []
    for _ in range(300):
        working.append(np.ones(int(rng.integers(10_000, 100_000))))  # 80-800 kB: now on the heap
        kept.append(np.ones(16))  # small survivors between them, which pin the space they leave
    del working


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads resident memory from /proc")
def test_freed_arrays_leave_resident_memory_after_the_trim() -> None:
    kept: list[np.ndarray] = []
    threads = [threading.Thread(target=_fragment_heap, args=(kept,)) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    before = _resident_mb()
    assert release_free_heap()  # glibc on Linux
    assert _resident_mb() < before - 100.0  # of the ~500 MB freed
