"""A query's parameters: what the API stores in ``queries.params`` and the worker reads back.

The API builds one :class:`QueryParams` from the request's form and the photo's EXIF and stores its JSON
(:meth:`QueryParams.to_json`); the query job reads it back (:meth:`QueryParams.from_json`) and the API serves
it as the query's ``params``. The JSON is the one stored before this model existed (the same keys in the same
order), and a row read back serves exactly the keys it was stored with (``exclude_unset``), so old rows are
served as they were. Positions are WGS84 degrees, headings degrees clockwise from north.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

QueryPreset = Literal["fast", "balanced", "accurate"]
"""A query's speed against accuracy; each names a ``QueryConfig`` (``geoloc/localize/query/config.py: PRESETS``)."""
QUERY_PRESETS: tuple[QueryPreset, ...] = ("fast", "balanced", "accurate")
"""The presets, fastest first."""
DEFAULT_QUERY_PRESET: QueryPreset = "balanced"
"""The preset of parameters stored before presets existed (they were answered with today's ``balanced``)."""


DEFAULT_PRIOR_RADIUS_M = 50.0
"""A GPS prior's radius (m, about 2 sigma) when neither the request nor the photo states one (a street canyon's fix)."""
MIN_GPS_PRIOR_RADIUS_M = 10.0
"""The least radius (m) a GPS prior gets from the accuracy its device states (none is believed to the metre)."""


def gps_prior_radius_m(stated_accuracy_m: float | None) -> float:
    """The radius (m, about 2 sigma) of the prior a photo's GPS fix gives, from the accuracy its device states.

    stated_accuracy_m: the photo's ``GPSHPositioningError`` or ``MAPGPSAccuracyMeters``
    (``geoloc.photos.capture``), None when it states none: then :data:`DEFAULT_PRIOR_RADIUS_M`. Phones state
    the radius of about 68 % confidence, 1.5 sigma per axis of a round Gaussian; the prior takes sigma as the
    stated accuracy itself (radius twice it, at least :data:`MIN_GPS_PRIOR_RADIUS_M`), wider than that reading
    because a fix beside tall buildings is off by more than its device says. Chosen on one track world
    (docs/measurements/tracks.md, "The GPS's stated accuracy").
    """
    if stated_accuracy_m is None:
        return DEFAULT_PRIOR_RADIUS_M
    return max(2.0 * stated_accuracy_m, MIN_GPS_PRIOR_RADIUS_M)


class PriorPosition(BaseModel):
    """A prior on the photo's position: a disc of ``radius_m`` (about 2 sigma) around (lat, lon)."""

    model_config = ConfigDict(frozen=True)

    lat: float
    lon: float
    radius_m: float
    source: Literal["request", "exif", "place"] | None = None
    """Where it came from: the request's lat/lon, the request's place (a name in the map), or the photo's EXIF GPS."""
    place: str | None = None
    """With source ``place``: the place's name as the map holds it (e.g. "Mannerheimintie 5")."""
    place_kind: str | None = None
    """With source ``place``: address, building, street or landmark."""
    gps_accuracy_m: float | None = None
    """With source ``exif``: the accuracy (m) the photo states for its fix, when it states one and the request
    gave no radius (``radius_m`` is then :func:`gps_prior_radius_m` of it)."""


class QueryParams(BaseModel):
    """How a query is answered.

    top_n: how many distinct locations to return; k: how many references to retrieve for identities;
    prior: the position prior (None: none); prior_heading_deg: the heading prior (deg from true north; the
    request's, else the photo's compass); prior_heading_accuracy_deg: the compass's accuracy (deg) when the
    heading came from the compass, None for a stated heading (and in parameters stored before it existed);
    focal_length_35mm: the request's 35 mm-equivalent focal length (None: the photo's EXIF, else a default
    field of view); original_filename: the uploaded file's name (kept for people, not used by the method);
    preset: the query stage's configuration by name (:data:`QueryPreset`; None in parameters stored before
    presets existed, which means :data:`DEFAULT_QUERY_PRESET`).
    """

    model_config = ConfigDict(frozen=True)

    top_n: int
    k: int
    prior: PriorPosition | None = None
    prior_heading_deg: float | None = None
    prior_heading_accuracy_deg: float | None = None
    focal_length_35mm: float | None = None
    original_filename: str | None = None
    preset: QueryPreset | None = None

    def to_json(self) -> dict[str, Any]:
        """The stored and served JSON form: the fields that were given (all of them when the API built it)."""
        return self.model_dump(mode="json", exclude_unset=True)

    @property
    def preset_name(self) -> QueryPreset:
        """The preset the query is answered with (:data:`DEFAULT_QUERY_PRESET` for parameters stored without one)."""
        return self.preset or DEFAULT_QUERY_PRESET

    @classmethod
    def from_json(cls, stored: Mapping[str, Any]) -> QueryParams:
        """The parameters read back from their stored JSON."""
        return cls.model_validate(stored)
