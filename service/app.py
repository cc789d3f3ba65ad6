"""The FastAPI application.

Settings, migrations at start, the request observer (request ids, log lines, metrics: :mod:`service.observe`),
body-size guard, errors, limits, the job waiter, the OpenAPI document of the running configuration, routes,
``/metrics``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from contracts.settings import Settings, get_settings
from db import connect, migrate
from db.files import open_store
from db.jobs import QueueFullError
from db.stats import stored_file_paths
from service import metrics, places, routes_maps, routes_queries, routes_references, routes_system, routes_tracks
from service.connections import BodyDeadline
from service.errors import error_body, error_response, install_error_handlers
from service.limits import queue_full, rate_limiter_for
from service.observe import RequestObserver
from service.routes_viewer import install_viewer
from service.spec import install_openapi
from service.uploads import clean_orphan_files, clean_stale_temp_files
from service.waiting import JobWaiter
from workers.broker import publisher_for
from workers.metrics import enable_metrics

log = logging.getLogger("geoloc.api")

Message = dict[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
FORM_OVERHEAD_BYTES = 64 * 1024
"""Allowance for multipart headers and text fields on top of a file's size limit."""


class BodySizeLimit:
    """Pure ASGI middleware: answer 413 when a request body exceeds the limit for its path.

    Checked from ``Content-Length`` up front or while streaming (chunked uploads).
    """

    def __init__(self, app: Any, limit_for_path: Callable[[str], int]) -> None:
        self.app = app
        self.limit_for_path = limit_for_path

    async def __call__(self, scope: Message, receive: Receive, send: Send) -> None:
        """Pass an ASGI request on to the app, or answer 413 once its body exceeds the path's limit."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limit_for_path(scope["path"])
        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length")
        message = f"request body is larger than the limit of {limit} bytes"
        if declared is not None and declared.isdigit() and int(declared) > limit:
            await self._drain(receive, int(declared))
            await self._send_413(send, message, limit)
            return
        stream = _StreamedBody(receive, send, limit, message)
        try:
            await self.app(scope, stream.receive, stream.send)
        except Exception:
            if stream.too_large and not stream.response_started:
                await self._send_413(send, message, limit)
                return
            raise

    @staticmethod
    async def _drain(receive: Receive, declared: int, cap: int = 1 << 30) -> None:
        """Read and discard a rejected body (up to ``cap``) so the client sees the 413, not a reset."""
        if declared > cap:
            return
        while True:
            event = await receive()
            if event["type"] != "http.request" or not event.get("more_body", False):
                return

    @staticmethod
    async def _send_413(send: Send, message: str, limit: int) -> None:
        """Send the 413 error response."""
        body = json.dumps(error_body("payload_too_large", message, {"limit_bytes": limit})).encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())],
            }
        )
        await send({"type": "http.response.body", "body": body})


class _StreamedBody:
    """One request's body streamed under a size limit (for :class:`BodySizeLimit`).

    ``receive`` counts the body's bytes and ends the body (a disconnect) once ``limit`` is passed;
    from then on ``send`` swallows the app's response and sends the 413 in its place.
    """

    def __init__(self, receive: Receive, send: Send, limit: int, message: str) -> None:
        self._receive = receive
        self._send = send
        self._limit = limit
        self._message = message
        self.received = 0
        self.too_large = False
        self.response_started = False

    async def receive(self) -> Message:
        """The next ASGI event of the request, or a disconnect once the body is too large."""
        event = await self._receive()
        if event["type"] == "http.request":
            self.received += len(event.get("body", b""))
            if self.received > self._limit:
                self.too_large = True
                return {"type": "http.disconnect"}
        return event

    async def send(self, event: Message) -> None:
        """Send the app's ASGI event, or, once the body is too large, the 413 instead of its response."""
        if self.too_large:
            if not self.response_started and event["type"] == "http.response.start":
                self.response_started = True
                await BodySizeLimit._send_413(self._send, self._message, self._limit)
            return
        self.response_started = self.response_started or event["type"] == "http.response.start"
        await self._send(event)


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the application (``uvicorn --factory service.app:create_app``)."""
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # This connection stays open while the API runs: SQLite deletes the WAL and its index when the last
        # connection closes, and re-creating them needs disk space; held open, requests can still open the
        # database (and read) on a full disk.
        db = connect(settings.database)
        try:
            version = migrate(db)
            referenced = stored_file_paths(db)
            store = app.state.file_store
            removed = clean_stale_temp_files(store) + clean_orphan_files(store, referenced)
            where = "PostgreSQL" if settings.database_url else settings.database_path
            log.info("database %s at schema %d (%d stale files removed)", where, version, removed)
            await app.state.job_waiter.start()
            try:
                yield
            finally:
                await app.state.job_waiter.stop()
        finally:
            db.close()

    app = FastAPI(
        title="geoloc",
        version="1",
        summary="Map-based visual geolocation: where was this photo taken, and which way did it look?",
        description=(
            "Upload a map (OpenStreetMap, GeoJSON, GeoPackage, FlatGeobuf or Shapefile buildings), ingest "
            "geo-tagged reference photos, then query photos for their position, heading and the buildings they "
            'show. Errors always have the body `{"error": {"code", "message", "details"}}`.\n\n'
            "Positions are WGS84 latitude/longitude in degrees; headings are degrees clockwise from north; "
            "times are ISO 8601 in UTC. Uploads are `multipart/form-data`; files are checked by their content, "
            "not their name. Request validation errors (a missing field, a value of the wrong type) are `422` "
            "with code `invalid_request` and `details.problems`, a list of `{field, problem}`.\n\n"
            "Under load: new work (references, queries) gets `429` `queue_full` with `Retry-After` while the job "
            "queue is full, an API key past its rate limit gets `429` `rate_limited` with `Retry-After`, and a "
            "write on a full disk gets `507` `insufficient_storage` with nothing stored.\n\n"
            "Every response carries `X-Request-ID`: the request's own (1 to 128 letters, digits and `._:/+=@-`; "
            "another value is `400` `invalid_request_id`) or one the service made; it is logged with the request "
            "and with the jobs it queued.\n\nThis document describes "
            "the running configuration: authentication, `401`/`403` and the rate limit appear only when API keys "
            "are configured."
        ),
        lifespan=lifespan,
    )
    app.state.settings = settings
    enable_metrics(settings)
    app.state.rate_limiter = rate_limiter_for(settings)
    app.state.job_waiter = JobWaiter(settings.database)
    app.state.file_store = open_store(settings.file_store_dir)
    app.state.job_publisher = publisher_for(settings)
    install_error_handlers(app)
    install_openapi(app, settings)

    @app.exception_handler(QueueFullError)
    async def _queue_full(_: Request, exc: QueueFullError) -> JSONResponse:
        error = queue_full(exc)
        return error_response(error.status, error.code, error.message, error.details, headers=error.headers)

    def limit_for_path(path: str) -> int:
        path = path.rstrip("/")
        if path == "/v1/maps":
            return settings.max_map_bytes + FORM_OVERHEAD_BYTES
        if path.startswith("/v1/maps/") and path.endswith("/tracks"):
            return settings.max_image_bytes * settings.max_track_frames + FORM_OVERHEAD_BYTES
        if path.startswith("/v1/maps/") and path.endswith(("/references", "/queries")):
            return settings.max_image_bytes + FORM_OVERHEAD_BYTES
        return max(settings.max_map_bytes, settings.max_image_bytes) + FORM_OVERHEAD_BYTES

    app.add_middleware(BodySizeLimit, limit_for_path=limit_for_path)
    app.add_middleware(BodyDeadline, idle_s=settings.http_body_idle_s, total_s=settings.http_body_timeout_s)
    app.add_middleware(RequestObserver)  # outermost: sees every answer, the body guards' 413 and 408 included

    app.include_router(routes_system.router)
    app.include_router(routes_maps.router)
    app.include_router(places.router)
    app.include_router(routes_references.router)
    app.include_router(routes_queries.router)
    app.include_router(routes_tracks.router)
    app.include_router(metrics.router)
    install_viewer(app)
    return app
