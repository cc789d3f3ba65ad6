"""Idle, slow-header and slow-body clients held against a running API while a normal client measures latency.

:func:`hold_slow_clients` opens raw sockets on loopback: ``idle`` that send nothing, ``slow_headers`` that send
a request head a byte every 0.5 s and never end it, ``slow_bodies`` uploads whose head is complete and whose
body trickles (10 bytes a second) or stops; meanwhile one normal client times ``GET /healthz`` and
``GET /v1/maps``. It records when the server closed each slow socket and what it answered. Used by
``tests/e2e/test_connection_limits.py`` (a CI-sized load) and ``benchmarks/bench_connections.py`` (1,000 idle).
"""

from __future__ import annotations

import contextlib
import selectors
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import httpx


@dataclass
class SlowClient:
    """One slow socket: its kind, when it opened, when the server closed it and what it answered first."""

    kind: str
    sock: socket.socket
    opened: float
    closed_after_s: float | None = None
    answer: bytes = b""


@dataclass
class LoadResult:
    """Latencies (ms) of the normal client by path, and the slow clients."""

    latencies_ms: dict[str, list[float]] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    clients: list[SlowClient] = field(default_factory=list)

    def p99(self, path: str) -> float:
        """The 99th percentile latency of ``path`` in ms."""
        values = sorted(self.latencies_ms[path])
        return values[min(len(values) - 1, int(0.99 * len(values)))]

    def closed_after(self, kind: str) -> list[float | None]:
        """Seconds after opening at which the server closed each slow socket of ``kind`` (None: still open)."""
        return [c.closed_after_s for c in self.clients if c.kind == kind]

    def figures(self) -> dict[str, Any]:
        """What a benchmark reports: p50/p99 per path, requests, errors, closing times per kind."""
        out: dict[str, Any] = {"errors": self.errors[:10]}
        for path, values in self.latencies_ms.items():
            ordered = sorted(values)
            out[path] = {"requests": len(ordered), "p50_ms": ordered[len(ordered) // 2], "p99_ms": self.p99(path)}
        for kind in sorted({c.kind for c in self.clients}):
            times = [t for t in self.closed_after(kind) if t is not None]
            out[f"{kind}_closed"] = {
                "count": len(self.closed_after(kind)),
                "closed": len(times),
                "min_s": min(times, default=None),
                "max_s": max(times, default=None),
                "answers": sorted(
                    {c.answer.split(b"\r\n", 1)[0].decode(errors="replace") for c in self.clients if c.kind == kind}
                ),
            }
        return out


def _connect(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    sock.setblocking(False)
    return sock


def hold_slow_clients(
    base_url: str,
    api_key: str | None,
    map_id: int,
    *,
    idle: int,
    slow_headers: int,
    slow_bodies: int,
    duration_s: float,
) -> LoadResult:
    """Open the slow clients, time the normal client for ``duration_s``, and watch the slow sockets close."""
    port = int(base_url.rsplit(":", 1)[1])
    result = LoadResult()
    now = time.monotonic()
    for _ in range(idle):
        result.clients.append(SlowClient("idle", _connect(port), now))
    for _ in range(slow_headers):
        client = SlowClient("slow_header", _connect(port), time.monotonic())
        client.sock.send(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        result.clients.append(client)
    key = f"X-API-Key: {api_key}\r\n".encode() if api_key else b""
    for n in range(slow_bodies):
        client = SlowClient("stalled_body" if n % 2 else "trickled_body", _connect(port), time.monotonic())
        head = (
            f"POST /v1/maps/{map_id}/references HTTP/1.1\r\nHost: x\r\nContent-Length: 200000\r\n"
            "Content-Type: multipart/form-data; boundary=b\r\n"
        ).encode()
        client.sock.send(head + key + b"\r\n--b\r\n")
        result.clients.append(client)
    stop = threading.Event()
    watcher = threading.Thread(target=_watch, args=(result.clients, stop), daemon=True)
    watcher.start()
    _measure(base_url, api_key, duration_s, result)
    stop.set()
    watcher.join(timeout=10)
    for client in result.clients:
        client.sock.close()
    return result


def _watch(clients: list[SlowClient], stop: threading.Event) -> None:
    """Trickle the slow heads and bodies; note when the server closes each socket and its first answer."""
    selector = selectors.DefaultSelector()
    for client in clients:
        selector.register(client.sock, selectors.EVENT_READ, client)
    open_clients = set(range(len(clients)))
    next_trickle = time.monotonic()
    while not stop.is_set() and open_clients:
        for key, _ in selector.select(timeout=0.05):
            client = key.data
            try:
                data = client.sock.recv(65536)
            except BlockingIOError:
                continue
            except OSError:
                data = b""
            if data:
                client.answer += data
                continue
            client.closed_after_s = time.monotonic() - client.opened
            selector.unregister(client.sock)
            open_clients.discard(clients.index(client))
        if time.monotonic() >= next_trickle:
            next_trickle += 0.5
            for client in clients:
                if client.closed_after_s is not None:
                    continue
                piece = {"slow_header": b"X", "trickled_body": b"0" * 5}.get(client.kind)
                if piece:
                    with contextlib.suppress(OSError):
                        client.sock.send(piece)
    selector.close()


def _measure(base_url: str, api_key: str | None, duration_s: float, result: LoadResult) -> None:
    """The normal client: ``/healthz`` and ``/v1/maps`` in turn on one keep-alive connection, for ``duration_s``."""
    headers = {"X-API-Key": api_key} if api_key else {}
    paths = ("/healthz", "/v1/maps")
    result.latencies_ms = {path: [] for path in paths}
    deadline = time.monotonic() + duration_s
    with httpx.Client(base_url=base_url, headers=headers, timeout=10) as client:
        while time.monotonic() < deadline:
            for path in paths:
                started = time.perf_counter()
                try:
                    response = client.get(path)
                    if response.status_code != 200:
                        result.errors.append(f"{path}: {response.status_code}")
                except httpx.HTTPError as exc:
                    result.errors.append(f"{path}: {type(exc).__name__}")
                result.latencies_ms[path].append(1000 * (time.perf_counter() - started))
            time.sleep(0.02)
