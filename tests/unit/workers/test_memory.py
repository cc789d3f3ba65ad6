"""The worker gives freed heap pages back (glibc), once idle or every few jobs: resident memory follows its use."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from workers import memory
from workers.memory import TRIM_EVERY_JOBS, HeapTrimmer, release_free_heap


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


def _counting_trims(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    trims: list[int] = []
    monkeypatch.setattr(memory, "release_free_heap", lambda: trims.append(1) or True)
    return trims


def test_heap_trimmer_trims_once_idle_long_enough_not_between_back_to_back_jobs(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    trims = _counting_trims(monkeypatch)
    heap = HeapTrimmer(idle_s=1.0)
    heap.job_done(10.0)
    assert not heap.idle(10.5) and trims == []  # the next query arrives within the second: its pages stay
    heap.job_done(11.0)
    assert heap.idle(12.0) and trims == [1]  # idle a second: trimmed once
    assert not heap.idle(20.0) and trims == [1]  # nothing since: no second trim


def test_heap_trimmer_trims_busy_workers_every_few_jobs_and_after_each_with_zero(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    trims = _counting_trims(monkeypatch)
    busy = HeapTrimmer(idle_s=1.0)
    for index in range(2 * TRIM_EVERY_JOBS):
        busy.job_done(float(index) * 0.1)  # never idle
    assert len(trims) == 2
    trims.clear()
    every = HeapTrimmer(idle_s=0.0)
    for index in range(3):
        every.job_done(float(index))
    assert len(trims) == 3
