"""Job threads: the same results in the same order as a loop, whatever the thread count."""

from __future__ import annotations

import multiprocessing
import threading
import time

import numpy as np
import pytest

from contracts.settings import reset_settings
from geoloc.core.camera import intrinsics_from_focal
from geoloc.core.parallel import JobThreads
from geoloc.localize.absolute_pose import group_proposal
from workers.context import method_context


@pytest.fixture(params=[1, 2, 4])
def threads(request: pytest.FixtureRequest) -> JobThreads:
    return JobThreads(int(request.param))


def test_the_workers_take_the_job_threads_from_the_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    for count in (1, 3):
        monkeypatch.setenv("GEOLOC_JOB_THREADS", str(count))
        reset_settings()
        assert method_context().threads == JobThreads(count)
        assert method_context() is method_context()  # once per process: one pool
    reset_settings()


def test_thread_map_is_an_ordered_map(threads: JobThreads) -> None:
    used: set[str] = set()

    def square(x: int) -> int:
        used.add(threading.current_thread().name)
        time.sleep(0.002)  # long enough for the helpers to take items
        return x * x

    assert threads.map(square, range(40)) == [x * x for x in range(40)]
    assert threads.map(square, []) == []
    assert len(used) <= threads.count
    if threads.count > 1:
        assert any(name.startswith("geoloc-job") for name in used)


def test_an_error_reaches_the_caller(threads: JobThreads) -> None:
    def fail_on_7(x: int) -> int:
        if x == 7:
            raise ValueError("item 7")
        return x

    with pytest.raises(ValueError, match="item 7"):
        threads.map(fail_on_7, range(20))
    assert threads.map(fail_on_7, range(7)) == list(range(7))  # the pool still works afterwards


def test_nested_calls_finish(threads: JobThreads) -> None:
    # An item that maps again on the (busy) pool: the caller drains its own items, nothing waits forever.
    rows = threads.map(lambda row: threads.map(lambda col: row * 10 + col, range(5)), range(6))
    assert rows == [[row * 10 + col for col in range(5)] for row in range(6)]
    inner = threads.beside(lambda: threads.map(lambda x: -x, range(9)))
    assert inner() == [-x for x in range(9)]


def test_pnp_proposals_on_threads_equal_the_loop(threads: JobThreads) -> None:
    # OpenCV's RANSAC per group, the query stage's use: the same poses on threads as one after another.
    rng = np.random.default_rng(3)
    intrinsics = intrinsics_from_focal(640, 480)
    groups = []
    for _ in range(6):
        xyz = np.c_[rng.uniform(-10, 10, 80), rng.uniform(15, 40, 80), rng.uniform(0, 12, 80)]
        cam = np.c_[xyz[:, 0], 1.6 - xyz[:, 2], xyz[:, 1]]  # camera at the origin looking north, y down
        projected = cam @ intrinsics.matrix.T
        px = projected[:, :2] / projected[:, 2:]
        px[:20] = rng.uniform(0, 480, (20, 2))  # outliers
        groups.append((xyz, px))
    sequential = [group_proposal(*group, intrinsics) for group in groups]
    parallel = threads.map(lambda group: group_proposal(*group, intrinsics), groups)
    for one, other in zip(sequential, parallel, strict=True):
        assert one is not None and other is not None
        assert np.array_equal(one[0], other[0]) and np.array_equal(one[1], other[1])


def _map_in_child(threads: JobThreads, queue: multiprocessing.Queue[list[int]]) -> None:
    queue.put(threads.map(lambda x: x + 1, range(10)))


def test_a_forked_child_makes_its_own_threads(threads: JobThreads) -> None:
    threads.map(lambda x: x, range(4))  # the parent's executor exists (and its threads do not survive a fork)
    context = multiprocessing.get_context("fork")
    queue: multiprocessing.Queue[list[int]] = context.Queue()
    child = context.Process(target=_map_in_child, args=(threads, queue))
    child.start()
    assert queue.get(timeout=30) == list(range(1, 11))
    child.join(30)
    assert child.exitcode == 0
