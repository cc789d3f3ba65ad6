"""What the client returns: the API's own models (:mod:`contracts.api`), under the client's names.

The service answers with these classes and the client parses its answers into them, so the two cannot
drift apart. Unknown fields are ignored (a newer service with more fields still parses). The client's
names are aliases of the API's schema names: :data:`Map` is ``MapOut``, :data:`Reference` is
``ReferenceOut``, :data:`Query` ``QueryOut``, :data:`Track` ``TrackOut``, :data:`Job` ``JobOut``,
:data:`License` ``LicenseOut``.
"""

from __future__ import annotations

from typing import Final

from contracts.api import (
    About,
    Feature,
    FeatureCollection,
    Health,
    Position,
    Readiness,
    ReferenceAccepted,
    ReferenceList,
)
from contracts.api import JobOut as Job
from contracts.api import LicenseOut as License
from contracts.api import MapOut as Map
from contracts.api import QueryOut as Query
from contracts.api import ReferenceOut as Reference
from contracts.api import TrackOut as Track
from contracts.jobs import WorkStatus as Status

FINAL_STATUSES: Final[frozenset[str]] = frozenset({"done", "failed"})
"""A reference's, a query's or a track's final statuses: ``done`` and ``failed``."""

__all__ = [
    "FINAL_STATUSES",
    "About",
    "Feature",
    "FeatureCollection",
    "Health",
    "Job",
    "License",
    "Map",
    "Position",
    "Query",
    "Readiness",
    "Reference",
    "ReferenceAccepted",
    "ReferenceList",
    "Status",
    "Track",
]
