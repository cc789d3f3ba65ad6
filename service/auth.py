"""API keys (``X-API-Key``) with scopes ``read`` and ``write`` and an optional tenant; off when no keys are configured.

Tenants: a key configured as ``KEY:SCOPES@TENANT`` (:func:`contracts.keys.parse_api_keys`) sees and changes
only its tenant's maps and what belongs to them (references, queries, jobs); a key without a tenant sees only
untenanted data, and so does every request while auth is off. :func:`request_caller` gives a route the
request's :class:`Caller`; :mod:`service.tenancy` looks rows up for it (another tenant's id is the same
``404`` as a missing one, never ``403``).
"""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import anyio.to_thread
from fastapi import Request, Security
from fastapi.security import APIKeyHeader

from contracts.keys import ApiKey
from contracts.settings import Settings
from service.deps import app_settings
from service.errors import ApiError
from service.limits import RateLimiter, RedisRateLimiter, rate_limited

api_key_header = APIKeyHeader(
    name="X-API-Key",
    auto_error=False,
    description=(
        "API key; scope `write` for maps and references, `read` for the rest (`write` implies `read`). "
        "Keys and their scopes are configured with `GEOLOC_API_KEYS` (`KEY:SCOPES@TENANT`, scopes joined by `+`, "
        "the tenant optional: a key sees only its tenant's maps, references, queries and jobs). "
        "A missing or unknown key is `401`, a key without the endpoint's scope is `403`. With no keys "
        "configured authentication is off and the service only listens on a loopback address."
    ),
)


@dataclass(frozen=True)
class Caller:
    """Who makes a request, as far as the data is concerned: the tenant of its key (None: untenanted)."""

    tenant: str | None = None


def _key_of(settings: Settings, presented: str) -> ApiKey | None:
    for key, record in settings.api_keys.items():
        if hmac.compare_digest(key.encode(), presented.encode()):
            return record
    return None


def request_caller(request: Request) -> Caller:
    """A dependency: the request's :class:`Caller` (no tenant while auth is off).

    Declared after :func:`require_scope` (the route's ``dependencies``), which already refused a missing or
    unknown key; this reads the header itself so that the OpenAPI schema is unchanged.
    """
    settings = app_settings(request)
    presented = request.headers.get("X-API-Key")
    record = _key_of(settings, presented) if settings.auth_enabled and presented else None
    return Caller(tenant=None if record is None else record.tenant)


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
        record = _key_of(settings, api_key)
        if record is None:
            raise ApiError(401, "unauthorized", "invalid API key")
        limiter: RateLimiter | RedisRateLimiter | None = request.app.state.rate_limiter
        if limiter is not None:
            if limiter.blocking:
                wait_s = await anyio.to_thread.run_sync(limiter.acquire, api_key)
            else:
                wait_s = limiter.acquire(api_key)
            if wait_s is not None:
                raise rate_limited(limiter, wait_s)
        if scope not in record.scopes:
            raise ApiError(403, "forbidden", f"this API key lacks the '{scope}' scope")

    return dependency


require_read = require_scope("read")
require_write = require_scope("write")


LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")
"""Hosts that only accept local connections: the API binds only to these while no API keys are configured."""


def is_loopback_host(host: str) -> bool:
    """Whether binding to ``host`` only accepts local connections (the rule for running without keys)."""
    return host in LOOPBACK_HOSTS or host.startswith("127.")
