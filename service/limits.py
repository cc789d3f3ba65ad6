"""Limits that keep the service answering under load: per-key request rates and the job queue's depth.

- :class:`RateLimiter`: a token bucket per API key, ``GEOLOC_RATE_LIMIT_PER_MIN`` tokens refilled
  evenly over a minute (so a key may burst up to a minute's worth). Past it a request gets ``429``
  ``rate_limited`` with ``Retry-After``: the seconds until one token is back. Only keys are limited:
  with no keys configured the service listens on loopback only and serves its one local user. The
  buckets live in the API process (one per ``geoloc serve``); several API processes would each
  apply the limit.
- :func:`require_queue_capacity`: new work (a reference upload, a query) is refused with ``429``
  ``queue_full`` and ``Retry-After`` while ``GEOLOC_MAX_QUEUED_JOBS`` jobs are waiting. The check
  runs before the upload is processed and again in the transaction that enqueues the job
  (``db.jobs.enqueue_job(max_queued=...)``), so the queue never grows past the limit. Reads are
  never refused for load.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from fastapi import Request

from db import connect
from db import jobs as job_store
from service.errors import ApiError
from service.settings import Settings

SECONDS_PER_MINUTE = 60.0


class RateLimiter:
    """Token buckets per key: ``per_minute`` requests a minute, refilled continuously; thread-safe."""

    def __init__(self, per_minute: int, clock: Callable[[], float] = time.monotonic) -> None:
        self.per_minute = per_minute
        self.refill_per_s = per_minute / SECONDS_PER_MINUTE
        self.clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}  # key -> (tokens, time of last update)
        self._lock = threading.Lock()

    def acquire(self, key: str) -> int | None:
        """Take one token for ``key``: None when the request may go on, else the seconds to wait."""
        now = self.clock()
        with self._lock:
            tokens, updated = self._buckets.get(key, (float(self.per_minute), now))
            tokens = min(float(self.per_minute), tokens + (now - updated) * self.refill_per_s)
            if tokens >= 1.0:
                self._buckets[key] = (tokens - 1.0, now)
                return None
            self._buckets[key] = (tokens, now)
            return max(1, math.ceil((1.0 - tokens) / self.refill_per_s))


def rate_limiter_for(settings: Settings) -> RateLimiter | None:
    """The app's limiter: None when auth is off or the limit is 0."""
    if not settings.auth_enabled or settings.rate_limit_per_min <= 0:
        return None
    return RateLimiter(settings.rate_limit_per_min)


def rate_limited(limiter: RateLimiter, wait_s: int) -> ApiError:
    """The ``429`` for a key past its limit."""
    return ApiError(
        429,
        "rate_limited",
        f"this API key made more than {limiter.per_minute} requests in a minute; retry in {wait_s} s",
        {"limit_per_min": limiter.per_minute, "retry_after_s": wait_s},
        headers={"Retry-After": str(wait_s)},
    )


def queue_full(exc: job_store.QueueFullError) -> ApiError:
    """The ``429`` for new work while the job queue is full."""
    return ApiError(
        429,
        "queue_full",
        f"the service is busy: {exc.depth} jobs are waiting (limit {exc.limit}); nothing was stored, "
        f"retry in {exc.retry_after_s} s",
        {"queued_jobs": exc.depth, "limit": exc.limit, "retry_after_s": exc.retry_after_s},
        headers={"Retry-After": str(exc.retry_after_s)},
    )


def require_queue_capacity(request: Request) -> None:
    """Dependency of the routes that enqueue jobs: ``429 queue_full`` while the queue is at its limit."""
    settings: Settings = request.app.state.settings
    db = connect(settings.database_path)
    try:
        job_store.check_queue_capacity(db, settings.max_queued_jobs)
    except job_store.QueueFullError as exc:
        raise queue_full(exc) from None
    finally:
        db.close()
