"""A Python client of the service's HTTP API: :class:`Client` (sync) and :class:`AsyncClient` (asyncio), on httpx.

A tool package (docs/client.md): the method, the workers and the service never import it; the CLI's
``geoloc ingest`` and the benchmarks talk to the service through it.
"""

from geoloc.client.asynchronous import AsyncClient
from geoloc.client.calls import Call, MapFields, QueryFields, ReferenceFields, Sent, TrackFields, Upload
from geoloc.client.errors import (
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
from geoloc.client.models import (
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
from geoloc.client.retry import RetryPolicy
from geoloc.client.sync import Client

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
]
