"""The HTTP API's request and response models, defined once: the service returns them, the client parses them.

One module per resource: :mod:`~contracts.api.maps` (maps, places), :mod:`~contracts.api.references`,
:mod:`~contracts.api.queries` (queries, tracks), :mod:`~contracts.api.system` (jobs, health, readiness,
about), :mod:`~contracts.api.errors` (the error body and every code) and :mod:`~contracts.api.geojson` (the
GeoJSON answers). The parts that workers compute are :mod:`contracts.answers`. The class names are the
OpenAPI document's schema names (``openapi.json``).
"""

from contracts.api.base import ApiModel, Attribution
from contracts.api.errors import CODES_BY_STATUS, ERROR_CODES, ErrorDetail, ErrorResponse
from contracts.api.geojson import Feature, FeatureCollection
from contracts.api.maps import MapList, MapOut, MapProgressOut, PlaceList, PlaceOut
from contracts.api.queries import FramePrior, QueryOut, TrackFromQueries, TrackOut
from contracts.api.references import Position, ReferenceAccepted, ReferenceList, ReferenceOut
from contracts.api.system import About, Health, JobOut, LicenseOut, Readiness

__all__ = [
    "CODES_BY_STATUS",
    "ERROR_CODES",
    "About",
    "ApiModel",
    "Attribution",
    "ErrorDetail",
    "ErrorResponse",
    "Feature",
    "FeatureCollection",
    "FramePrior",
    "Health",
    "JobOut",
    "LicenseOut",
    "MapList",
    "MapOut",
    "MapProgressOut",
    "PlaceList",
    "PlaceOut",
    "Position",
    "QueryOut",
    "ReferenceAccepted",
    "ReferenceList",
    "ReferenceOut",
    "Readiness",
    "TrackFromQueries",
    "TrackOut",
]
