"""Limits that keep the service answering under load: per-key request rates and the job queue's depth.

- :class:`RateLimiter`: a token bucket per API key, ``GEOLOC_RATE_LIMIT_PER_MIN`` tokens refilled
  evenly over a minute (so a key may burst up to a minute's worth). Past it a request gets ``429``
  ``rate_limited`` with ``Retry-After``: the seconds until one token is back. Only keys are limited:
  with no keys configured the service listens on loopback only and serves its one local user. In the
  embedded profile the buckets live in the API process; in the distributed profile
  (:class:`RedisRateLimiter`) they live in the broker's Redis, updated by one atomic script per
  request, so every API process draws from the same bucket of a key. If Redis cannot be reached the
  request is let through (logged): the limit protects the service, it must not take it down.
- :func:`require_queue_capacity`: new work (a reference upload, a query) is refused with ``429``
  ``queue_full`` and ``Retry-After`` while ``GEOLOC_MAX_QUEUED_JOBS`` jobs are waiting. The check
  runs before the upload is processed and again in the transaction that enqueues the job
  (``db.jobs.enqueue_job(max_queued=...)``), so the queue never grows past the limit. Reads are
  never refused for load.
"""

from __future__ import annotations

import hashlib
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from fastapi import Request

from contracts.settings import Settings
from db import jobs as job_store
from service.deps import app_settings, open_db
from service.errors import ApiError
from workers.broker import redis_client

SECONDS_PER_MINUTE = 60.0
log = logging.getLogger("geoloc.api")


class RateLimiter:
    """Token buckets per key in this process: ``per_minute`` requests a minute, refilled continuously; thread-safe."""

    blocking = False
    """Whether :meth:`acquire` does network I/O (then the API calls it from a worker thread)."""

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


_TOKEN_BUCKET_LUA = """
local capacity = tonumber(ARGV[1])
local refill_per_s = tonumber(ARGV[2])
local clock = redis.call('TIME')
local now = tonumber(clock[1]) + tonumber(clock[2]) / 1000000
local state = redis.call('HMGET', KEYS[1], 'tokens', 'updated')
local tokens = tonumber(state[1]) or capacity
local updated = tonumber(state[2]) or now
tokens = math.min(capacity, tokens + math.max(now - updated, 0) * refill_per_s)
local allowed = 0
if tokens >= 1 then
    tokens = tokens - 1
    allowed = 1
end
redis.call('HSET', KEYS[1], 'tokens', tostring(tokens), 'updated', tostring(now))
redis.call('EXPIRE', KEYS[1], math.ceil(capacity / refill_per_s) + 60)
return {allowed, tostring(tokens)}
"""


class RedisRateLimiter:
    """The same token buckets as :class:`RateLimiter`, kept in Redis so that all API processes share them.

    A bucket is a hash ``geoloc:rate:<sha256 of the key>`` (the key itself is never stored) updated by one
    Lua script, atomic on the server, on the server's clock; it expires once it would be full again.
    """

    blocking = True
    """:meth:`acquire` talks to Redis: the API calls it from a worker thread."""

    def __init__(self, per_minute: int, redis_url: str) -> None:
        self.per_minute = per_minute
        self.refill_per_s = per_minute / SECONDS_PER_MINUTE
        self._script: Any = redis_client(redis_url).register_script(_TOKEN_BUCKET_LUA)

    def acquire(self, key: str) -> int | None:
        """Take one token for ``key``: None when the request may go on, else the seconds to wait."""
        bucket = "geoloc:rate:" + hashlib.sha256(key.encode()).hexdigest()
        try:
            allowed, tokens = self._script(keys=[bucket], args=[self.per_minute, self.refill_per_s])
        except Exception as exc:  # Redis unreachable: let the request through rather than fail it
            log.warning("rate limit not checked, Redis unreachable: %s", exc)
            return None
        if int(allowed):
            return None
        return max(1, math.ceil((1.0 - float(tokens)) / self.refill_per_s))


def rate_limiter_for(settings: Settings) -> RateLimiter | RedisRateLimiter | None:
    """The app's limiter: None when auth is off or the limit is 0; shared through Redis when distributed."""
    if not settings.auth_enabled or settings.rate_limit_per_min <= 0:
        return None
    if settings.broker_url is not None:
        return RedisRateLimiter(settings.rate_limit_per_min, settings.broker_url)
    return RateLimiter(settings.rate_limit_per_min)


def rate_limited(limiter: RateLimiter | RedisRateLimiter, wait_s: int) -> ApiError:
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
    settings = app_settings(request)
    db = open_db(settings)
    try:
        job_store.check_queue_capacity(db, settings.max_queued_jobs)
    except job_store.QueueFullError as exc:
        raise queue_full(exc) from None
    finally:
        db.close()
