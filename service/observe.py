"""Each request observed: its request id, its one log line, its HTTP metrics (a pure ASGI middleware, outermost).

- **Request id.** An ``X-Request-ID`` header is honoured (1 to 128 letters, digits and ``._:/+=@-``; anything else
  is a ``400`` ``invalid_request_id``), else one is made (:func:`contracts.logs.new_request_id`); it is returned in
  the response's ``X-Request-ID``, set in :data:`contracts.logs.REQUEST_ID` while the request runs (every log line
  carries it, and :func:`db.jobs.enqueue_job` stores it on the jobs the request queues).
- **Log line.** One line per request on the logger ``geoloc.request`` (INFO): ``method``, ``path``, ``route`` (the
  route's template, ``/v1/maps/{map_id}``), ``status``, ``duration_ms``, ``client``, and ``reason`` (the error's
  code) for a rejection.
- **Metrics** (when on, :mod:`workers.metrics`): ``geoloc_http_requests_total{method, route, status}``,
  ``geoloc_http_request_duration_seconds{method, route}`` (from the request's start to the response's last byte,
  s), ``geoloc_rejections_total{status, reason}`` for 413, 415, 422 and 429 (the reason is the error
  body's ``code``, e.g. ``payload_too_large``, ``invalid_request``, ``queue_full``, ``rate_limited``). A path that
  matches no route counts as route ``unmatched``, so that scanners cannot grow the series.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Awaitable, Callable
from typing import Any, Final

from contracts.logs import REQUEST_ID, new_request_id, request_id_from_header
from service.errors import error_body
from workers.metrics import DURATION_BUCKETS_S, enabled_folder

Message = dict[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]

log = logging.getLogger("geoloc.request")

REJECTION_STATUSES: Final = frozenset({413, 415, 422, 429})
"""Statuses counted in ``geoloc_rejections_total``, by the error's code."""
HTTP_BUCKETS_S: Final = (0.001, 0.0025, *DURATION_BUCKETS_S)
"""Latency buckets (s): reads take a millisecond, a query that waits for its answer seconds."""
_REASON_BODY_BYTES: Final = 4096
"""How much of a rejection's body is read for its error code (error bodies are small)."""

_instruments: dict[str, Any] = {}


def _metrics() -> dict[str, Any] | None:
    """The API's HTTP instruments, made once metrics are on in this process (None while they are off)."""
    folder = enabled_folder()
    if folder is None:
        return None
    if _instruments.get("folder") != folder:  # made again if the folder changed (tests)
        from prometheus_client import Counter, Histogram

        _instruments["folder"] = folder
        _instruments["requests"] = Counter(
            "geoloc_http_requests",
            "HTTP requests by method, route template and status",
            ["method", "route", "status"],
            registry=None,
        )
        _instruments["latency"] = Histogram(
            "geoloc_http_request_duration_seconds",
            "HTTP request latency by method and route template, from the request's start to its last byte (s)",
            ["method", "route"],
            buckets=HTTP_BUCKETS_S,
            registry=None,
        )
        _instruments["rejections"] = Counter(
            "geoloc_rejections",
            "Requests refused with 413, 415, 422 or 429, by status and error code",
            ["status", "reason"],
            registry=None,
        )
    return _instruments


class RequestObserver:
    """Pure ASGI middleware: the request id, the request's log line and its metrics (module docstring)."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: Message, receive: Receive, send: Send) -> None:
        """Run the request with its id set; answer 400 for an invalid ``X-Request-ID``."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        header = dict(scope.get("headers") or []).get(b"x-request-id")
        request_id = request_id_from_header(header.decode("latin-1") if header is not None else None)
        exchange = _Exchange(send, request_id)
        token = REQUEST_ID.set(request_id)
        try:
            if request_id is None:
                await exchange.refuse_request_id()
            else:
                await self.app(scope, receive, exchange.send)
        except Exception:
            exchange.status = exchange.status or 500
            raise
        finally:
            _record(scope, exchange, time.perf_counter() - started)
            REQUEST_ID.reset(token)


class _Exchange:
    """One response as it is sent: its status, the request id added to its headers, a rejection's error code."""

    def __init__(self, send: Send, request_id: str | None) -> None:
        self._send = send
        self.request_id = request_id
        self.status = 0
        self.body = b""

    async def send(self, event: Message) -> None:
        """Pass an ASGI event on: the request id into the response's headers, a rejection's body kept."""
        if event["type"] == "http.response.start":
            self.status = int(event["status"])
            if self.request_id is not None:
                headers = [(k, v) for k, v in event.get("headers", []) if k.lower() != b"x-request-id"]
                event = {**event, "headers": [*headers, (b"x-request-id", self.request_id.encode())]}
        elif event["type"] == "http.response.body" and self.status in REJECTION_STATUSES:
            self.body = (self.body + event.get("body", b""))[:_REASON_BODY_BYTES]
        await self._send(event)

    async def refuse_request_id(self) -> None:
        """Answer ``400`` ``invalid_request_id`` (with a fresh id of our own in the response header)."""
        self.request_id = new_request_id()
        REQUEST_ID.set(self.request_id)
        body = json.dumps(
            error_body(
                "invalid_request_id",
                "X-Request-ID must be 1 to 128 letters, digits or the characters ._:/+=@-",
            )
        ).encode()
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
        await self.send({"type": "http.response.start", "status": 400, "headers": headers})
        await self.send({"type": "http.response.body", "body": body})

    @property
    def reason(self) -> str | None:
        """A rejection's error code (``error.code`` of its body), ``unknown`` when the body has none."""
        if self.status not in REJECTION_STATUSES:
            return None
        try:
            code = json.loads(self.body)["error"]["code"]
        except (ValueError, KeyError, TypeError):
            return "unknown"
        return str(code)


def route_template(scope: Message) -> str:
    """The matched route's path template (``/v1/queries/{query_id}``), ``unmatched`` when no route matched."""
    path = getattr(scope.get("route"), "path", None)
    return path if isinstance(path, str) and path else "unmatched"


def _record(scope: Message, exchange: _Exchange, seconds: float) -> None:
    """The request's log line and metrics."""
    method, route, status, reason = scope["method"], route_template(scope), exchange.status, exchange.reason
    client = scope.get("client")
    fields: dict[str, Any] = {
        "method": method,
        "path": scope["path"],
        "route": route,
        "status": status,
        "duration_ms": round(seconds * 1e3, 2),
        "client": client[0] if client else None,
        "request_id": exchange.request_id,
    }
    if reason is not None:
        fields["reason"] = reason
    log.info("%s %s %d %.1f ms", method, scope["path"], status, seconds * 1e3, extra=fields)
    instruments = _metrics()
    if instruments is None:
        return
    instruments["requests"].labels(method, route, str(status)).inc()
    instruments["latency"].labels(method, route).observe(seconds)
    if reason is not None:
        instruments["rejections"].labels(str(status), reason).inc()
