"""What the sync and the async client share: configuration, headers, reading answers into results or errors."""

from __future__ import annotations

from typing import Any, TypedDict, TypeVar, Unpack

import httpx

from client.calls import Call, Sent
from client.errors import api_error
from client.models import FINAL_STATUSES
from client.retry import RetryPolicy

T = TypeVar("T")
DEFAULT_TIMEOUT_S = 120.0
"""Seconds one HTTP request may take (connect: 10 s); a query with ``wait_s`` adds that to it."""
POLL_SLACK_S = 15.0
"""Extra read time for a long poll, on top of its ``wait_s``."""
IDLE_CONNECTION_EXPIRY_S = 2.0
"""Seconds a pooled connection may sit idle before the client drops it rather than reuse it.

Below the service's ``GEOLOC_HTTP_KEEP_ALIVE_S`` (default 5 s) on purpose: a client that reuses a connection just
as the service closes it for idleness sends its request into a closing socket and gets no answer (httpx's own
default, 5 s, equals the service's and did so once in the distributed hour's 19,190 requests).
"""


def pool_limits(max_connections: int | None = 100) -> httpx.Limits:
    """Pool limits for httpx with :data:`IDLE_CONNECTION_EXPIRY_S` (``max_connections`` None: no cap)."""
    keep = None if max_connections is None else min(max_connections, 20)
    return httpx.Limits(
        max_connections=max_connections, max_keepalive_connections=keep, keepalive_expiry=IDLE_CONNECTION_EXPIRY_S
    )


class ClientOptions(TypedDict, total=False):
    """A client's options: ``timeout_s`` (one request, s), ``retry`` (when to try again), ``limits`` (httpx's pool)."""

    timeout_s: float
    retry: RetryPolicy
    limits: httpx.Limits


class ClientBase:
    """A client of one service (``base_url``), with an optional API key (sent as ``X-API-Key``).

    Options (:class:`ClientOptions`): ``timeout_s`` for one request (default 120 s), ``retry`` (default
    ``RetryPolicy()``), ``limits`` (httpx's connection-pool limits, default :func:`pool_limits`). The sync and the
    async client add ``transport`` (an httpx transport, for tests) and ``sleep`` (how to wait, for tests).
    """

    def __init__(self, base_url: str, api_key: str | None, **options: Unpack[ClientOptions]) -> None:
        self.base_url = base_url.rstrip("/")
        self.retry = options.get("retry") or RetryPolicy()
        self._timeout_s = options.get("timeout_s", DEFAULT_TIMEOUT_S)
        self._timeout = httpx.Timeout(self._timeout_s, connect=10.0)
        self._headers = {"X-API-Key": api_key} if api_key else {}
        self._limits = options.get("limits") or pool_limits()

    def _http_args(self) -> dict[str, Any]:
        """The httpx client's arguments: base URL, headers, timeout, pool limits."""
        return {"base_url": self.base_url, "headers": self._headers, "timeout": self._timeout, "limits": self._limits}

    def _request_args(self, call: Call[Any]) -> dict[str, Any]:
        """``httpx`` arguments of one try of ``call`` (a long poll gets its ``wait_s`` on top of the timeout)."""
        args: dict[str, Any] = {"params": call.params or None, "headers": call.headers or None}
        if call.json is not None:
            args["json"] = call.json
        elif call.data:
            args["data"] = call.data
        if call.files:
            args["files"] = call.files
        body = call.json if call.json is not None else call.data
        wait_s = float(call.params.get("wait_s", 0.0) or body.get("wait_s", 0.0))
        if wait_s > 0:
            args["timeout"] = httpx.Timeout(self._timeout_s + wait_s + POLL_SLACK_S, connect=10.0)
        return args


def finish(call: Call[T], response: httpx.Response, attempts: int) -> Sent[T]:
    """The call's result, or its :class:`~client.errors.ApiError` raised."""
    if not response.is_success:
        raise api_error(response, attempts)
    return Sent(call.read(response), response.status_code, attempts)


def is_final(value: Any) -> bool:
    """Whether a reference or a query (anything with ``status``) is ``done`` or ``failed``."""
    return getattr(value, "status", None) in FINAL_STATUSES
