"""Connection limits uvicorn lacks: a deadline for a request's headers and one for its body.

uvicorn closes an idle keep-alive connection (``timeout_keep_alive``) and caps connections and requests
(``limit_concurrency``), but it waits forever for the headers of a connection that sends none or trickles them,
and for a body that stops or trickles. Here:

- :func:`protocol_class` gives uvicorn an h11 protocol that closes a connection whose request head is not
  complete ``GEOLOC_HTTP_HEADER_TIMEOUT_S`` after the connection opened, or ``GEOLOC_HTTP_KEEP_ALIVE_S`` plus that
  after the previous response ended (an idle keep-alive connection is uvicorn's to close, at its keep-alive
  timeout: the deadline must not cut it sooner, when a client may be reusing it);
- :class:`BodyDeadline` (ASGI middleware) answers ``408`` ``request_timeout`` (and closes the connection) when
  no body bytes came for ``GEOLOC_HTTP_BODY_IDLE_S`` or the whole body took over ``GEOLOC_HTTP_BODY_TIMEOUT_S``.

Both cost one timer per connection or body read, on the event loop: no thread waits on a slow client.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Awaitable, Callable
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from contracts.settings import Settings
from service.errors import error_body

Message = dict[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]


class HeaderDeadlineProtocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline for each request's head (:attr:`header_timeout_s` seconds)."""

    header_timeout_s = 10.0
    keep_alive_s = 5.0
    _header_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        """Start the head's deadline as the connection opens."""
        super().connection_made(transport)
        self._arm_header_deadline(self.header_timeout_s)

    def on_response_complete(self) -> None:
        """Start the next head's deadline as a response ends (after the keep-alive time the next may wait)."""
        super().on_response_complete()
        self._arm_header_deadline(self.keep_alive_s + self.header_timeout_s)

    def connection_lost(self, exc: Exception | None) -> None:
        """Drop the deadline with the connection."""
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None
        super().connection_lost(exc)

    def _arm_header_deadline(self, after_s: float) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
        if not self.transport.is_closing():
            self._header_timer = self.loop.call_later(after_s, self._header_deadline)

    def _header_deadline(self) -> None:
        """Close the connection if it is still waiting for a complete request head (no request is running)."""
        self._header_timer = None
        waiting = self.conn.their_state is h11.IDLE and (self.cycle is None or self.cycle.response_complete)
        if waiting and not self.transport.is_closing():
            self.logger.debug("closing a connection whose request head did not arrive in time")
            self.transport.close()


def protocol_class(settings: Settings) -> type[HeaderDeadlineProtocol]:
    """The protocol uvicorn runs (its ``http=`` argument), with the settings' header deadline."""
    deadlines = {"header_timeout_s": settings.http_header_timeout_s, "keep_alive_s": settings.http_keep_alive_s}
    return type("GeolocH11Protocol", (HeaderDeadlineProtocol,), deadlines)


def uvicorn_options(settings: Settings) -> dict[str, Any]:
    """The connection options of uvicorn from the settings (``service/__main__.py`` passes them to ``uvicorn.run``)."""
    return {
        "http": protocol_class(settings),
        "timeout_keep_alive": settings.http_keep_alive_s,
        "limit_concurrency": settings.http_max_connections,
        "h11_max_incomplete_event_size": settings.http_max_header_bytes,
        "proxy_headers": True,
        "forwarded_allow_ips": settings.forwarded_allow_ips,
        "timeout_graceful_shutdown": settings.worker_grace_s,
    }


class BodyDeadline:
    """Pure ASGI middleware: ``408`` when a request's body stalls (``idle_s``) or takes too long (``total_s``)."""

    def __init__(self, app: Any, idle_s: float, total_s: float) -> None:
        self.app = app
        self.idle_s = idle_s
        self.total_s = total_s

    async def __call__(self, scope: Message, receive: Receive, send: Send) -> None:
        """Pass the request on with a receive that keeps the deadlines, or answer ``408`` when one passes."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        body = _DeadlinedBody(receive, send, self.idle_s, time.monotonic() + self.total_s)
        try:
            await self.app(scope, body.receive, body.send)
        except Exception:
            if body.timed_out and not body.response_started:
                await _send_408(send, body.reason)
                return
            raise


class _DeadlinedBody:
    """One request's body read under the deadlines; once one passes, the app's answer becomes the ``408``."""

    def __init__(self, receive: Receive, send: Send, idle_s: float, deadline: float) -> None:
        self._receive = receive
        self._send = send
        self._idle_s = idle_s
        self._deadline = deadline
        self.body_done = False
        self.timed_out = False
        self.response_started = False
        self.reason = ""

    async def receive(self) -> Message:
        """The next ASGI event; a disconnect once a deadline passed (the app then stops reading)."""
        if self.body_done or self.timed_out:
            return await self._receive()
        left = self._deadline - time.monotonic()
        wait_s = min(self._idle_s, left)
        try:
            event = await asyncio.wait_for(self._receive(), timeout=max(wait_s, 0.0))
        except TimeoutError:
            self.timed_out = True
            self.reason = (
                f"the request body stalled: no bytes for {self._idle_s:g} s"
                if wait_s >= self._idle_s
                else "the request body took too long to arrive"
            )
            return {"type": "http.disconnect"}
        if event["type"] != "http.request" or not event.get("more_body", False):
            self.body_done = True
        return event

    async def send(self, event: Message) -> None:
        """The app's event, or, once a deadline passed, the ``408`` in place of its response."""
        if self.timed_out:
            if not self.response_started and event["type"] == "http.response.start":
                self.response_started = True
                await _send_408(self._send, self.reason)
            return
        self.response_started = self.response_started or event["type"] == "http.response.start"
        await self._send(event)


async def _send_408(send: Send, reason: str) -> None:
    """The ``408`` ``request_timeout`` answer; ``Connection: close`` (the rest of the body is not read)."""
    message = f"{reason}; nothing was stored: send the request again"
    body = json.dumps(error_body("request_timeout", message)).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),
    ]
    await send({"type": "http.response.start", "status": 408, "headers": headers})
    await send({"type": "http.response.body", "body": body})
