"""When the client tries a request again, and how long it sleeps first.

One policy for the sync and the async client: a retryable status (by default 429 and 503) or a
transport error is tried again up to ``retries`` times; the sleep is the answer's ``Retry-After`` when it
has one, else exponential backoff with jitter (``backoff_s`` * 2^(attempt-1), at most ``max_backoff_s``).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import httpx

from client.errors import RateLimitedError, WaitTimeoutError, retry_after_s

T = TypeVar("T")

DEFAULT_RETRY_STATUSES = frozenset({429, 503})
"""Answers the client tries again: rate limited or queue full (429), not available now (503)."""
TRANSIENT_STATUSES = frozenset({408, 429, 500, 502, 503, 504})
"""A wider set for batch tools that would rather retry a failed upload (``geoloc ingest``)."""


@dataclass(frozen=True)
class RetryPolicy:
    """How often and how patiently to retry.

    ``retries``: extra tries after the first; ``statuses``: HTTP statuses retried; ``transport_errors``:
    whether connection errors and timeouts are retried; ``stop``: when it returns True no retry is made
    (a batch tool's switch when the service is gone).
    """

    retries: int = 3
    backoff_s: float = 0.5
    max_backoff_s: float = 30.0
    statuses: frozenset[int] = DEFAULT_RETRY_STATUSES
    transport_errors: bool = True
    stop: Callable[[], bool] = field(default=lambda: False)

    def delay_after(self, attempt: int, outcome: httpx.Response | httpx.TransportError) -> float | None:
        """Seconds to sleep before try ``attempt + 1``, or None to give up on ``outcome``."""
        if attempt > self.retries or self.stop():
            return None
        if isinstance(outcome, httpx.TransportError):
            return self.backoff(attempt) if self.transport_errors else None
        if outcome.status_code not in self.statuses:
            return None
        after = retry_after_s(outcome)
        return after if after is not None else self.backoff(attempt)

    def backoff(self, attempt: int) -> float:
        """Exponential backoff with +-25 % jitter (s)."""
        return float(min(self.backoff_s * 2 ** (attempt - 1), self.max_backoff_s) * random.uniform(0.75, 1.25))


@dataclass
class Waiting:
    """A wait's clock: the deadline and the growing pause between two polls (exponential backoff).

    ``timeout_s``: the whole wait (s); pauses start at ``first_s`` and double up to ``most_s``.
    """

    timeout_s: float
    clock: Callable[[], float]
    first_s: float = 0.25
    most_s: float = 5.0
    deadline: float = 0.0
    pause_s: float = 0.0

    def __post_init__(self) -> None:
        """Start the clock."""
        self.deadline = self.clock() + self.timeout_s
        self.pause_s = self.first_s

    def remaining_s(self) -> float:
        """Seconds left (0 when past the deadline)."""
        return max(self.deadline - self.clock(), 0.0)

    def next_pause_s(self) -> float:
        """The next pause (s): ``first_s``, then doubling up to ``most_s``."""
        pause = self.pause_s
        self.pause_s = min(self.pause_s * 2.0, self.most_s)
        return pause


class WaitLoop(Generic[T]):
    """The steps of a wait that both clients run: the pause to spend, then done, a sleep, or a time-out.

    Each round: :meth:`begin` gives the pause (s) the fetch may spend as a long poll; :meth:`after` takes
    the value read (or the :class:`RateLimitedError` left after the retries) and says how long to sleep
    before the next round (the pause the fetch did not spend, or the ``Retry-After``), or None when
    ``done(value)``. Past ``timeout_s`` it raises :class:`WaitTimeoutError` with the last value read.
    """

    def __init__(self, timeout_s: float, done: Callable[[T], bool], what: str, clock: Callable[[], float]) -> None:
        self.timeout_s, self.done, self.what, self.clock = timeout_s, done, what, clock
        self.waiting = Waiting(timeout_s, clock)
        self.last: T | None = None
        self.pause_s = self.waiting.next_pause_s()
        self.started = 0.0

    def begin(self) -> float:
        """Start a round: the pause (s) its fetch may spend."""
        self.started = self.clock()
        return self.pause_s

    def after(self, value: T | None, limited: RateLimitedError | None = None) -> float | None:
        """End a round: None when ``value`` is final, else the seconds to sleep; WaitTimeoutError past the deadline."""
        retry_after = 0.0
        if limited is not None:
            retry_after = limited.retry_after_s or self.pause_s
        else:
            self.last = value
            if value is not None and self.done(value):
                return None
        remaining = self.waiting.remaining_s()
        if remaining <= 0:
            status: Any = getattr(self.last, "status", None)
            raise WaitTimeoutError(
                f"{self.what} not final after {self.timeout_s:g} s (last status: {status})", self.last
            )
        sleep_s = min(max(self.pause_s - (self.clock() - self.started), retry_after), remaining)
        self.pause_s = self.waiting.next_pause_s()
        return sleep_s
