"""API keys (``X-API-Key``) with scopes ``read`` and ``write``; off when no keys are configured."""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable

import anyio.to_thread
from fastapi import Request, Security
from fastapi.security import APIKeyHeader

from contracts.settings import Settings
from service.deps import app_settings
from service.errors import ApiError
from service.limits import RateLimiter, RedisRateLimiter, rate_limited

api_key_header = APIKeyHeader(
    name="X-API-Key",
    auto_error=False,
    description=(
        "API key; scope `write` for maps and references, `read` for the rest (`write` implies `read`). "
        "Keys and their scopes are configured with `GEOLOC_API_KEYS` (`KEY:SCOPES`, scopes joined by `+`). "
        "A missing or unknown key is `401`, a key without the endpoint's scope is `403`. With no keys "
        "configured authentication is off and the service only listens on a loopback address."
    ),
)


def _scopes_of(settings: Settings, presented: str) -> frozenset[str] | None:
    for key, scopes in settings.api_keys.items():
        if hmac.compare_digest(key.encode(), presented.encode()):
            return scopes
    return None


def require_scope(scope: str) -> Callable[..., Awaitable[None]]:
    """A dependency that admits requests whose key has ``scope``, within the key's rate limit.

    Everyone is admitted when auth is off; rate limits are :mod:`service.limits`.

    The scope is declared on the security requirement, so the OpenAPI schema shows it per operation
    (and :mod:`service.spec` drops it when no keys are configured). Async: in the embedded profile it does
    no I/O and needs no worker thread; the distributed profile's shared rate limit asks Redis from one.
    """

    async def dependency(request: Request, api_key: str | None = Security(api_key_header, scopes=[scope])) -> None:
        settings = app_settings(request)
        if not settings.auth_enabled:
            return
        if not api_key:
            raise ApiError(401, "unauthorized", "missing API key: send it in the X-API-Key header")
        scopes = _scopes_of(settings, api_key)
        if scopes is None:
            raise ApiError(401, "unauthorized", "invalid API key")
        limiter: RateLimiter | RedisRateLimiter | None = request.app.state.rate_limiter
        if limiter is not None:
            if limiter.blocking:
                wait_s = await anyio.to_thread.run_sync(limiter.acquire, api_key)
            else:
                wait_s = limiter.acquire(api_key)
            if wait_s is not None:
                raise rate_limited(limiter, wait_s)
        if scope not in scopes:
            raise ApiError(403, "forbidden", f"this API key lacks the '{scope}' scope")

    return dependency


require_read = require_scope("read")
require_write = require_scope("write")


LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")
"""Hosts that only accept local connections: the API binds only to these while no API keys are configured."""


def is_loopback_host(host: str) -> bool:
    """Whether binding to ``host`` only accepts local connections (the rule for running without keys)."""
    return host in LOOPBACK_HOSTS or host.startswith("127.")
