"""The API's connection settings (``GEOLOC_HTTP_*``, ``GEOLOC_FORWARDED_ALLOW_IPS``), a part of :class:`Settings`.

Kept in their own class so that ``contracts/settings.py`` stays within the house's module size; the one settings
object, :class:`contracts.settings.Settings`, inherits them (its README table lists them first) and reads them
from the environment like every other setting.
"""

from __future__ import annotations

from pydantic import Field
from pydantic_settings import BaseSettings


class HttpSettings(BaseSettings):
    """How many connections the API takes and how long it waits for a slow client (docs/operations.md)."""

    http_max_connections: int = Field(
        default=4096,
        ge=16,
        description="open connections and running requests the API takes at once (uvicorn's `limit_concurrency`; "
        "past it, `503`); `geoloc serve` raises its open-files limit to fit",
    )
    http_keep_alive_s: float = Field(default=5.0, ge=0.1, description="an idle keep-alive connection is closed then")
    http_header_timeout_s: float = Field(
        default=10.0,
        ge=0.1,
        description="a request's headers must be complete within this long of the connection opening (or of the "
        "previous response plus the keep-alive time); a connection that sends none or too slowly is closed",
    )
    http_max_header_bytes: int = Field(default=32768, ge=1024, description="largest request head (`400` above)")
    http_body_idle_s: float = Field(
        default=30.0, ge=0.1, description="an upload that sends no body bytes for this long gets `408` and is closed"
    )
    http_body_timeout_s: float = Field(
        default=900.0, ge=1, description="the whole request body must arrive within this long (else `408`, closed)"
    )
    forwarded_allow_ips: str = Field(
        default="127.0.0.1",
        description="addresses of reverse proxies whose `X-Forwarded-For`/`-Proto` are believed (comma-separated, "
        "`*` for any); the client address the logs show (docs/operations.md)",
    )
