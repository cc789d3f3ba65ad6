"""Threads for the independent parts of one job (a query or a reference label).

The worker pool's processes are the parallelism between jobs; inside one job a few parts do not depend
on each other (the features beside the facade analysis, each shortlisted reference's matching and RANSAC,
each reference's PnP proposal). They run on ``GEOLOC_JOB_THREADS`` threads, so that a query on a
machine with an idle core finishes sooner. The heavy calls (OpenCV, numpy's BLAS, onnxruntime) release the
GIL; each part computes exactly what it computes alone, so results do not depend on the thread count.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar, cast

from contracts.settings import get_settings

T = TypeVar("T")
R = TypeVar("R")

_lock = threading.Lock()
_executors: dict[tuple[int, int], ThreadPoolExecutor] = {}
"""Executors by (process id, threads): a forked child makes its own (threads do not survive a fork)."""


def job_threads() -> int:
    """Threads one job may use (``GEOLOC_JOB_THREADS``)."""
    return get_settings().job_threads


def _pool() -> ThreadPoolExecutor | None:
    threads = job_threads()
    if threads <= 1:
        return None
    key = (os.getpid(), threads)
    with _lock:
        if key not in _executors:
            # The helpers are the extra threads: the calling thread does its share too.
            _executors[key] = ThreadPoolExecutor(threads - 1, thread_name_prefix="geoloc-job")
        return _executors[key]


def thread_map(function: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[function(x) for x in items]``, in order, on up to ``GEOLOC_JOB_THREADS`` threads."""
    items = list(items)
    pool = _pool()
    if pool is None or len(items) < 2:
        return [function(item) for item in items]
    results: list[R | None] = [None] * len(items)
    next_index = itertools.count()  # its next() is atomic: each item is taken by exactly one thread

    def drain() -> None:
        while (index := next(next_index)) < len(items):
            results[index] = function(items[index])

    helpers = [pool.submit(drain) for _ in range(min(job_threads() - 1, len(items) - 1))]
    try:
        drain()  # the calling thread works too, so a busy pool (or a nested call) never leaves it waiting
    finally:
        for helper in helpers:
            if not helper.cancel():  # one that never started has nothing left to do
                helper.result()
    return cast(list[R], results)


def run_beside(function: Callable[[], R]) -> Callable[[], R]:
    """Start ``function()`` on a job thread now; the returned callable waits for its result.

    With one job thread (or none free by the time the result is asked for), ``function`` runs then, in the
    asking thread.
    """
    pool = _pool()
    if pool is None:
        return function
    future = pool.submit(function)

    def result() -> R:
        return function() if future.cancel() else future.result()

    return result
