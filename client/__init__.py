"""A Python client of the service's HTTP API: :class:`Client` (sync) and :class:`AsyncClient` (asyncio), on httpx.

A top-level tool package (docs/client.md) on nothing but :mod:`contracts`: its answers are the API's own models
(:mod:`contracts.api`). The method, the workers and the service never import it; the CLI's ``geoloc ingest`` and
the benchmarks talk to the service through it. ``geoloc.client`` is its deprecated alias for one release.
"""

from client.asynchronous import AsyncClient
from client.base import IDLE_CONNECTION_EXPIRY_S, pool_limits
from client.calls import Call, MapFields, QueryFields, ReferenceFields, Sent, TrackFields, Upload
from client.errors import (
    ApiError,
    AuthError,
    ConflictError,
    GeolocClientError,
    InvalidRequestError,
    NotFoundError,
    RateLimitedError,
    ServerError,
    ServiceUnreachableError,
    WaitTimeoutError,
)
from client.models import (
    About,
    Feature,
    FeatureCollection,
    Health,
    Job,
    Map,
    Query,
    Readiness,
    Reference,
    ReferenceAccepted,
    ReferenceList,
    Track,
)
from client.retry import RetryPolicy
from client.sync import Client

__all__ = [
    "About",
    "ApiError",
    "AsyncClient",
    "AuthError",
    "Call",
    "Client",
    "ConflictError",
    "Feature",
    "FeatureCollection",
    "GeolocClientError",
    "IDLE_CONNECTION_EXPIRY_S",
    "Health",
    "InvalidRequestError",
    "Job",
    "Map",
    "MapFields",
    "NotFoundError",
    "Query",
    "QueryFields",
    "Track",
    "TrackFields",
    "RateLimitedError",
    "Readiness",
    "Reference",
    "ReferenceAccepted",
    "ReferenceFields",
    "ReferenceList",
    "RetryPolicy",
    "Sent",
    "ServerError",
    "ServiceUnreachableError",
    "Upload",
    "WaitTimeoutError",
    "pool_limits",
]
