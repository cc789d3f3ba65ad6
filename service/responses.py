"""What the routes share to answer: timestamps from rows, and each route's documented error statuses.

The answers' models themselves are the API's contract, :mod:`contracts.api`.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, overload

from contracts.api import ErrorResponse


@overload
def timestamp(value: float) -> datetime: ...
@overload
def timestamp(value: None) -> None: ...
def timestamp(value: float | None) -> datetime | None:
    """Unix seconds -> aware UTC datetime (None stays None)."""
    return datetime.fromtimestamp(value, tz=UTC) if value is not None else None


def error_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route: each status answered with :class:`~contracts.api.ErrorResponse`.

    Routes list the statuses their own code answers with; :mod:`service.spec` adds the ones that
    depend on the configuration or the request's form (auth, rate limit, multipart, full disk).
    """
    return {status: {"model": ErrorResponse} for status in statuses}
