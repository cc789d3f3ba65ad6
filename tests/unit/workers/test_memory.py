"""After a job the worker settles the heap: cycles collected, survivors frozen, freed pages given back (glibc)."""

from __future__ import annotations

import gc
import threading
import weakref
from pathlib import Path

import numpy as np
import pytest

from workers.memory import release_free_heap, settle_heap


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


class _Node:
    """A weak-referenceable object to put in reference cycles."""

    def __init__(self) -> None:
        self.other: object = None


def test_settling_collects_cycles_and_freezes_what_survives() -> None:
    """The job's cyclic garbage is freed; what outlives the job leaves the collector's generations."""
    garbage, kept = _Node(), _Node()
    garbage.other, kept.other = garbage, kept  # two cycles: one dropped, one kept
    gone = weakref.ref(garbage)
    del garbage
    frozen_before = gc.get_freeze_count()
    try:
        settle_heap()
        assert gone() is None  # collected before the freeze, not frozen with the rest
        assert gc.get_freeze_count() > frozen_before
        assert not any(obj is kept for obj in gc.get_objects())  # out of every collection's walk
        assert len(gc.get_objects()) < 1_000  # a collection walks only what was made since
    finally:
        gc.unfreeze()  # the rest of the test session collects as usual
