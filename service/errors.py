"""One JSON error body for every 4xx/5xx: ``{"error": {"code": ..., "message": ..., "details": ...}}``."""

from __future__ import annotations

import errno
import logging
import os
import re
import sqlite3
from pathlib import Path
from typing import Any

import psycopg
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from contracts.api import CODES_BY_STATUS
from db.outages import is_database_unavailable, outage_reason
from service.deps import app_settings

log = logging.getLogger("geoloc.api")


class ApiError(Exception):
    """An error answered as ``status`` with a machine code, a human message and optional details."""

    def __init__(
        self,
        status: int,
        code: str,
        message: str,
        details: dict[str, Any] | None = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.details = details
        self.headers = headers


def error_body(code: str, message: str, details: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON body of an error response."""
    error: dict[str, Any] = {"code": code, "message": message}
    if details:
        error["details"] = details
    return {"error": error}


def error_response(
    status: int, code: str, message: str, details: dict[str, Any] | None = None, headers: dict[str, str] | None = None
) -> JSONResponse:
    """A JSON error response."""
    return JSONResponse(error_body(code, message, details), status_code=status, headers=headers)


def _validation_message(exc: RequestValidationError) -> tuple[str, list[dict[str, Any]]]:
    problems = []
    for error in exc.errors():
        location = ".".join(str(part) for part in error.get("loc", ()) if part not in ("body", "query", "path"))
        problems.append({"field": location, "problem": error.get("msg", "invalid")})
    text = "; ".join(f"{p['field']}: {p['problem']}" if p["field"] else p["problem"] for p in problems)
    return f"invalid request: {text}", problems


OPENAPI_METHODS = ("get", "put", "post", "delete", "options", "head", "patch", "trace")
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
NEARLY_FULL_BYTES = 1024 * 1024
"""Below this much free space an I/O error from SQLite is taken for a full disk."""
DATABASE_RETRY_AFTER_S = 5
"""``Retry-After`` (seconds) of a ``503`` ``database_unavailable``."""
DATABASE_UNAVAILABLE_MESSAGE = (
    "the database is unavailable for now (down, restarting, read-only or busy): nothing was stored; retry later"
)
DISK_FULL_MESSAGE = (
    "the server's storage is full: nothing was stored; retry once space has been freed (reads keep working meanwhile)"
)


def is_disk_full(exc: BaseException, data_dir: Path | None = None) -> bool:
    """Whether ``exc`` (or an exception it was raised from) means the disk or quota is full.

    Covers ``OSError`` ENOSPC/EDQUOT (writing an upload, creating a folder), SQLite's ``SQLITE_FULL``
    ("database or disk is full") and PostgreSQL's ``disk_full`` (SQLSTATE 53100). SQLite reports some
    writes that found no space (growing the WAL index, for one) as a generic I/O error; such an error
    counts as a full disk when the file system of ``data_dir`` has less than :data:`NEARLY_FULL_BYTES` left.
    """
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in DISK_FULL_ERRNOS:
            return True
        if isinstance(current, psycopg.errors.DiskFull):
            return True
        if isinstance(current, sqlite3.Error):
            code = getattr(current, "sqlite_errorcode", None)
            if code == sqlite3.SQLITE_FULL or "disk is full" in str(current):
                return True
            if (code is not None and code & 0xFF == sqlite3.SQLITE_IOERR) or "disk I/O error" in str(current):
                return data_dir is not None and free_bytes(data_dir) < NEARLY_FULL_BYTES
        current = current.__cause__ or current.__context__
    return False


def free_bytes(path: Path) -> int:
    """Bytes available to this process on the file system of ``path`` (a large number if unknown)."""
    try:
        stats = os.statvfs(path)
    except OSError:
        return 1 << 62
    return stats.f_bavail * stats.f_frsize


def allowed_methods(app: Any, path: str) -> list[str]:
    """The methods the app's OpenAPI document lists for the operations at ``path``, sorted (upper case).

    Starlette's own ``405`` names only the methods of the first route whose path matched, while
    ``GET`` and ``DELETE`` of one resource are separate routes here; the document has them all.
    """
    methods: set[str] = set()
    for template, operations in app.openapi().get("paths", {}).items():
        pattern = "^" + re.sub(r"\\{[^/]+?\\}", "[^/]+", re.escape(template)) + "$"
        if re.match(pattern, path):
            methods |= {method.upper() for method in operations if method in OPENAPI_METHODS}
    return sorted(methods)


def database_unavailable() -> JSONResponse:
    """The ``503`` ``database_unavailable`` answer, with ``Retry-After``."""
    headers = {"Retry-After": str(DATABASE_RETRY_AFTER_S)}
    return error_response(503, "database_unavailable", DATABASE_UNAVAILABLE_MESSAGE, headers=headers)


def install_error_handlers(app: FastAPI) -> None:
    """Route every error through :func:`error_response`."""

    @app.exception_handler(ApiError)
    async def _api_error(_: Request, exc: ApiError) -> JSONResponse:
        return error_response(exc.status, exc.code, exc.message, exc.details, headers=exc.headers)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = CODES_BY_STATUS.get(exc.status_code, "error")
        message = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        headers = dict(getattr(exc, "headers", None) or {})
        if exc.status_code == 405 and (methods := allowed_methods(request.app, request.url.path)):
            headers["Allow"] = ", ".join(methods)
            message = f"method {request.method} is not allowed here; allowed: {', '.join(methods)}"
        return error_response(exc.status_code, code, message, headers=headers or None)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_: Request, exc: RequestValidationError) -> JSONResponse:
        message, problems = _validation_message(exc)
        return error_response(422, "invalid_request", message, {"problems": problems})

    async def _storage_error(request: Request, exc: Exception) -> JSONResponse:
        if is_disk_full(exc, app_settings(request).data_dir):
            log.error("disk full on %s %s: %s", request.method, request.url.path, exc)
            return error_response(507, "insufficient_storage", DISK_FULL_MESSAGE)
        if is_database_unavailable(exc):
            log.warning("database unavailable on %s %s: %s", request.method, request.url.path, outage_reason(exc))
            return database_unavailable()
        return await _unexpected(request, exc)

    app.add_exception_handler(OSError, _storage_error)
    app.add_exception_handler(sqlite3.Error, _storage_error)
    app.add_exception_handler(psycopg.Error, _storage_error)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
        return error_response(500, "internal_error", f"internal error: {type(exc).__name__}")
