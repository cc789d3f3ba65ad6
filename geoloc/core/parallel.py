"""Threads for the independent parts of one job (a query or a reference label).

The worker pool's processes are the parallelism between jobs; inside one job a few parts do not depend
on each other (the features beside the facade analysis, each shortlisted reference's matching and RANSAC,
each reference's PnP proposal). They run on a :class:`JobThreads` (``GEOLOC_JOB_THREADS`` threads in the
workers, :mod:`workers.context`), so that a query on a machine with an idle core finishes sooner. The heavy
calls (OpenCV, numpy's BLAS, onnxruntime) release the GIL; each part computes exactly what it computes alone,
so results do not depend on the thread count.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar, cast

T = TypeVar("T")
R = TypeVar("R")


class JobThreads:
    """``count`` threads for one job's independent parts; owns its thread pool (made on first use).

    The calling thread does its share, so the pool holds ``count - 1`` helpers; with ``count`` 1 everything
    runs in the calling thread. A forked child makes its own pool (threads do not survive a fork). Two
    objects with the same ``count`` compare equal (the pool is not part of the value).
    """

    __slots__ = ("_executors", "_lock", "count")

    def __init__(self, count: int = 1) -> None:
        if count < 1:
            raise ValueError(f"job threads must be at least 1, got {count}")
        self.count = int(count)
        self._lock = threading.Lock()
        self._executors: dict[int, ThreadPoolExecutor] = {}
        """The helpers' executor by process id."""

    def __repr__(self) -> str:
        """``JobThreads(count)``."""
        return f"JobThreads({self.count})"

    def __eq__(self, other: object) -> bool:
        """Equal thread counts."""
        return isinstance(other, JobThreads) and other.count == self.count

    def __hash__(self) -> int:
        """Hash of the thread count."""
        return hash((JobThreads, self.count))

    def _pool(self) -> ThreadPoolExecutor | None:
        if self.count <= 1:
            return None
        pid = os.getpid()
        with self._lock:
            if pid not in self._executors:
                # The helpers are the extra threads: the calling thread does its share too.
                self._executors[pid] = ThreadPoolExecutor(self.count - 1, thread_name_prefix="geoloc-job")
            return self._executors[pid]

    def map(self, function: Callable[[T], R], items: Iterable[T]) -> list[R]:
        """``[function(x) for x in items]``, in order, on up to ``count`` threads."""
        items = list(items)
        pool = self._pool()
        if pool is None or len(items) < 2:
            return [function(item) for item in items]
        results: list[R | None] = [None] * len(items)
        next_index = itertools.count()  # its next() is atomic: each item is taken by exactly one thread

        def drain() -> None:
            while (index := next(next_index)) < len(items):
                results[index] = function(items[index])

        helpers = [pool.submit(drain) for _ in range(min(self.count - 1, len(items) - 1))]
        try:
            drain()  # the calling thread works too, so a busy pool (or a nested call) never leaves it waiting
        finally:
            for helper in helpers:
                if not helper.cancel():  # one that never started has nothing left to do
                    helper.result()
        return cast(list[R], results)

    def beside(self, function: Callable[[], R]) -> Callable[[], R]:
        """Start ``function()`` on a job thread now; the returned callable waits for its result.

        With one job thread (or none free by the time the result is asked for), ``function`` runs then, in the
        asking thread.
        """
        pool = self._pool()
        if pool is None:
            return function
        future = pool.submit(function)

        def result() -> R:
            return function() if future.cancel() else future.result()

        return result


ONE_THREAD = JobThreads(1)
"""Everything in the calling thread (the default of the lower functions that take ``threads``)."""
