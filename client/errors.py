"""The client's exceptions, built from the service's error body ``{"error": {"code", "message", "details"}}``.

:class:`ApiError` is every answer outside 2xx (the HTTP ``status``, the API's ``code``, ``message`` and
``details``; a body that is not the API's, from a proxy say, gives ``code`` None and its text as the
message); its subclasses sort the broad kinds so that callers can catch one. Transport failures after
the retries are :class:`ServiceUnreachableError`; a wait that runs out is :class:`WaitTimeoutError`.
"""

from __future__ import annotations

from typing import Any

import httpx

MAX_RETRY_AFTER_S = 60.0
"""Longest ``Retry-After`` honoured (s): a longer one is waited for this long before the next try."""


class GeolocClientError(Exception):
    """Base of everything the client raises."""


class ServiceUnreachableError(GeolocClientError):
    """The service did not answer (connection, timeout or protocol errors) after all retries."""


class WaitTimeoutError(GeolocClientError, TimeoutError):
    """A wait ran out before the job was final; ``last`` is the last state read (a model)."""

    def __init__(self, message: str, last: Any) -> None:
        super().__init__(message)
        self.last = last


class ApiError(GeolocClientError):
    """The service answered an error: ``status`` (HTTP), ``code`` (the API's, e.g. ``not_found``), ``message``.

    ``details`` holds the API's extra facts (limits, distances, ``problems`` of a 422); ``retry_after_s``
    the ``Retry-After`` header (s) when there was one; ``attempts`` how many tries the client made.
    """

    def __init__(
        self,
        status: int,
        code: str | None,
        message: str,
        details: dict[str, Any] | None = None,
        *,
        retry_after_s: float | None = None,
        attempts: int = 1,
    ) -> None:
        super().__init__(f"{status} {code or 'error'}: {message}")
        self.status = status
        self.code = code
        self.message = message
        self.details = details
        self.retry_after_s = retry_after_s
        self.attempts = attempts


class InvalidRequestError(ApiError):
    """400, 413, 415 or 422: the request or its file was refused (``code`` says why: ``outside_map``, ...)."""


class AuthError(ApiError):
    """401 (missing or unknown API key) or 403 (the key lacks the scope)."""


class NotFoundError(ApiError):
    """404: no such map, reference, query or job."""


class ConflictError(ApiError):
    """409: not possible in the current state (e.g. ``not_ready``: a reference not labelled yet)."""


class RateLimitedError(ApiError):
    """429 (``rate_limited`` or ``queue_full``) still answered when the retries ran out."""


class ServerError(ApiError):
    """5xx: the service failed (``internal_error``), is not ready, or its storage is full."""


_KINDS: dict[int, type[ApiError]] = {401: AuthError, 403: AuthError, 404: NotFoundError, 409: ConflictError}
_KINDS |= {400: InvalidRequestError, 413: InvalidRequestError, 415: InvalidRequestError}
_KINDS |= {422: InvalidRequestError, 429: RateLimitedError}


def retry_after_s(response: httpx.Response) -> float | None:
    """The ``Retry-After`` header in seconds (0 .. :data:`MAX_RETRY_AFTER_S`), None when absent or a date."""
    try:
        return min(max(float(response.headers.get("retry-after", "")), 0.0), MAX_RETRY_AFTER_S)
    except ValueError:
        return None


def error_fields(response: httpx.Response) -> tuple[str | None, str, dict[str, Any] | None]:
    """(code, message, details) from the API's error body, or from whatever came back instead."""
    try:
        error = response.json().get("error") or {}
        return error.get("code"), str(error.get("message") or response.reason_phrase), error.get("details")
    except (ValueError, AttributeError):
        text = response.text.strip().replace("\n", " ")
        return None, (text[:200] or response.reason_phrase or f"HTTP {response.status_code}"), None


def api_error(response: httpx.Response, attempts: int = 1) -> ApiError:
    """The exception for an error answer, of the subclass its status belongs to."""
    code, message, details = error_fields(response)
    status = response.status_code
    kind = _KINDS.get(status, ServerError if status >= 500 else ApiError)
    return kind(status, code, message, details, retry_after_s=retry_after_s(response), attempts=attempts)
