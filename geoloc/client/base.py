"""What the sync and the async client share: configuration, headers, reading answers into results or errors."""

from __future__ import annotations

from typing import Any, TypeVar

import httpx

from geoloc.client.calls import Call, Sent
from geoloc.client.errors import WaitTimeoutError, api_error
from geoloc.client.models import FINAL_STATUSES
from geoloc.client.retry import RetryPolicy

T = TypeVar("T")
DEFAULT_TIMEOUT_S = 120.0
"""Seconds one HTTP request may take (connect: 10 s); a query with ``wait_s`` adds that to it."""
POLL_SLACK_S = 15.0
"""Extra read time for a long poll, on top of its ``wait_s``."""


class ClientBase:
    """Configuration of a client: base URL, ``X-API-Key``, timeouts and the retry policy."""

    def __init__(self, base_url: str, api_key: str | None, timeout_s: float, retry: RetryPolicy | None) -> None:
        self.base_url = base_url.rstrip("/")
        self.retry = retry or RetryPolicy()
        self._timeout_s = timeout_s
        self._timeout = httpx.Timeout(timeout_s, connect=10.0)
        self._headers = {"X-API-Key": api_key} if api_key else {}

    def _request_args(self, call: Call[Any]) -> dict[str, Any]:
        """``httpx`` arguments of one try of ``call`` (a long poll gets its ``wait_s`` on top of the timeout)."""
        args: dict[str, Any] = {"params": call.params or None, "headers": call.headers or None}
        if call.data:
            args["data"] = call.data
        if call.files:
            args["files"] = call.files
        wait_s = float(call.params.get("wait_s", 0.0) or call.data.get("wait_s", 0.0))
        if wait_s > 0:
            args["timeout"] = httpx.Timeout(self._timeout_s + wait_s + POLL_SLACK_S, connect=10.0)
        return args


def finish(call: Call[T], response: httpx.Response, attempts: int) -> Sent[T]:
    """The call's result, or its :class:`~geoloc.client.errors.ApiError` raised."""
    if not response.is_success:
        raise api_error(response, attempts)
    return Sent(call.read(response), response.status_code, attempts)


def is_final(value: Any) -> bool:
    """Whether a reference or a query (anything with ``status``) is ``done`` or ``failed``."""
    return getattr(value, "status", None) in FINAL_STATUSES


def timed_out(what: str, timeout_s: float, last: Any) -> WaitTimeoutError:
    """The :class:`WaitTimeoutError` of a wait for ``what`` that ran out, with its last state."""
    status = getattr(last, "status", None)
    return WaitTimeoutError(f"{what} not final after {timeout_s:g} s (last status: {status})", last)
