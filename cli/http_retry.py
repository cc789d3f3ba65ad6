"""An HTTP client for the service that retries what may succeed later.

Connection errors, 408, 429 and 5xx are retried with exponential backoff and jitter (``Retry-After``
honoured, at most 60 s); :func:`error_fields` reads the service's error body
``{"error": {"code", "message", "details"}}`` or whatever came back instead.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable
from typing import Any

import httpx

RETRY_STATUSES = frozenset({408, 429, 500, 502, 503, 504})
"""Answers worth another try: the request may succeed later."""
MAX_BACKOFF_S = 30.0
"""Longest wait between two tries (s)."""


class ServiceUnreachableError(Exception):
    """The service did not answer (connection or protocol errors) after all retries."""


def error_fields(response: httpx.Response) -> tuple[str | None, str, dict[str, Any] | None]:
    """(code, message, details) from the API's error body, or from whatever came back."""
    try:
        error = response.json().get("error") or {}
        return error.get("code"), str(error.get("message") or response.reason_phrase), error.get("details")
    except (ValueError, AttributeError):
        text = response.text.strip().replace("\n", " ")
        return None, (text[:200] or response.reason_phrase or f"HTTP {response.status_code}"), None


def _retry_after_s(response: httpx.Response) -> float | None:
    raw = response.headers.get("retry-after", "")
    try:
        return min(max(float(raw), 0.0), 60.0)
    except ValueError:
        return None


class RetryingClient:
    """An ``httpx.Client`` with retries of transient errors and exponential backoff."""

    def __init__(
        self,
        url: str,
        api_key: str | None,
        *,
        retries: int = 5,
        backoff_s: float = 0.5,
        timeout_s: float = 120.0,
        transport: httpx.BaseTransport | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        headers = {"X-API-Key": api_key} if api_key else {}
        self.http = httpx.Client(
            base_url=url.rstrip("/"),
            headers=headers,
            timeout=httpx.Timeout(timeout_s, connect=10.0),
            transport=transport,
        )
        self.retries = retries
        self.backoff_s = backoff_s
        self.sleep = sleep
        self.stop = threading.Event()

    def close(self) -> None:
        """Close the connection pool."""
        self.http.close()

    def request(self, method: str, path: str, **kwargs: Any) -> tuple[httpx.Response, int]:
        """The response and the number of attempts; retries 408/429/5xx and transport errors.

        Returns the last response when retries run out on a retryable status; raises
        :class:`ServiceUnreachableError` when they run out on transport errors.
        """
        attempt = 0
        while True:
            attempt += 1
            try:
                response = self.http.request(method, path, **kwargs)
            except httpx.TransportError as exc:
                if attempt > self.retries or self.stop.is_set():
                    raise ServiceUnreachableError(f"{type(exc).__name__}: {exc}") from exc
                self.sleep(self._delay(attempt, None))
                continue
            if response.status_code not in RETRY_STATUSES or attempt > self.retries or self.stop.is_set():
                return response, attempt
            self.sleep(self._delay(attempt, _retry_after_s(response)))

    def alive(self) -> bool:
        """Whether ``/healthz`` answers now (one try)."""
        try:
            return self.http.get("/healthz", timeout=5.0).status_code == 200
        except httpx.HTTPError:
            return False

    def _delay(self, attempt: int, retry_after: float | None) -> float:
        if retry_after is not None:
            return retry_after
        return float(min(self.backoff_s * 2 ** (attempt - 1), MAX_BACKOFF_S) * random.uniform(0.75, 1.25))
