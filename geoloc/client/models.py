"""What the client returns: the API's answers as typed pydantic models.

The parts the workers compute (a query's ``result``, a reference's ``estimated`` pose and
``buildings_seen``) are the API's own models from :mod:`contracts.answers`; the envelopes around them
mirror the API's response models (``service.models``, a layer above this one) field by field, which
``tests/unit/client/test_models.py`` checks against ``openapi.json``. Unknown fields are ignored, so a
newer service with more fields still parses.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from contracts.answers import BoundingBox, BuildingInPhoto, EstimatedPose, LatLon, QueryResult, TrackFrameResult

Status = Literal["queued", "processing", "done", "failed"]
"""A reference's or a query's status; ``done`` and ``failed`` are final."""
FINAL_STATUSES: frozenset[str] = frozenset({"done", "failed"})


class _Model(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)


class Map(_Model):
    """A stored map (``POST/GET /v1/maps``); ``duplicate`` when the same file was uploaded before."""

    id: int
    name: str
    status: str = "done"
    """``queued``, ``processing``, ``done`` (usable) or ``failed`` (``error`` says why)."""
    error: str | None = None
    error_code: str | None = None
    error_details: dict[str, Any] = {}
    job_id: int | None = None
    progress: dict[str, int] = {}
    """The parse's progress: ``elements`` read, ``buildings`` so far."""
    source_filename: str
    source_format: str
    sha256: str
    bbox: BoundingBox
    origin: LatLon
    building_count: int
    facade_count: int
    reference_count: int = 0
    repair_report: dict[str, Any]
    read_options: dict[str, str] = {}
    attribution: str
    created_at: datetime
    duplicate: bool = False


class ReferenceAccepted(_Model):
    """A reference upload's answer: the reference, the job that labels it, ``duplicate`` if already held."""

    id: int
    map_id: int
    job_id: int | None
    status: str
    sha256: str
    duplicate: bool = False


class Position(_Model):
    """A WGS84 position (degrees) and where it came from (``exif`` or ``request``)."""

    lat: float
    lon: float
    source: Literal["exif", "request"]


class Reference(_Model):
    """A reference photo and, once ``done``, what labelling found (``estimated``, ``buildings_seen``)."""

    id: int
    map_id: int
    status: Status
    error: str | None = None
    job_id: int | None = None
    sha256: str
    original_filename: str | None = None
    width: int
    height: int
    position: Position
    prior_heading_deg: float | None = None
    prior_heading_accuracy_deg: float | None = None
    focal_length_35mm: float | None = None
    sequence_id: str | None = None
    capture_time: str | None = None
    placement: Literal["alone", "sequence"] = "alone"
    estimated: EstimatedPose | None = None
    buildings_seen: list[BuildingInPhoto] | None = None
    timings: dict[str, float] | None = None
    attribution: str
    created_at: datetime
    updated_at: datetime


class ReferenceList(_Model):
    """One page of a map's references; pass ``next_after_id`` as ``after_id`` for the next one."""

    map_id: int
    references: list[Reference]
    total: int
    counts: dict[str, int]
    walks_placing: int
    """Walk placements queued or running; while above 0, references in walks may still move."""
    next_after_id: int | None
    attribution: str

    @property
    def labelling(self) -> int:
        """The map's references still being labelled (``queued`` or ``processing``)."""
        return self.counts.get("queued", 0) + self.counts.get("processing", 0)

    @property
    def status(self) -> Literal["labelling", "placing", "placed"]:
        """Where the map's poses stand: references being labelled, else walks being placed, else all final."""
        if self.labelling:
            return "labelling"
        return "placing" if self.walks_placing else "placed"

    @property
    def placed(self) -> bool:
        """Whether every pose of the map is final: nothing being labelled and no walk placement pending."""
        return self.status == "placed"


class Query(_Model):
    """A query: its status and, once ``done``, its answer (``result``: ranked locations, heatmap, buildings)."""

    id: int
    map_id: int
    status: Status
    error: str | None = None
    job_id: int | None = None
    params: dict[str, Any]
    result: QueryResult | None = None
    attribution: str
    created_at: datetime | None = None
    updated_at: datetime | None = None


class Track(_Model):
    """A track: its status and its frames in order (``frames``: each with its pose once ``done``)."""

    id: int
    map_id: int
    status: Status
    error: str | None = None
    job_id: int | None = None
    params: dict[str, Any]
    frames: list[TrackFrameResult]
    search: dict[str, Any] | None = None
    timings_ms: dict[str, float] | None = None
    attribution: str
    created_at: datetime | None = None
    updated_at: datetime | None = None


class Job(_Model):
    """A background job (``GET /v1/jobs/{id}``)."""

    id: int
    kind: str
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    attempts: int
    max_attempts: int
    payload: dict[str, Any]
    result: dict[str, Any] | None = None
    error: str | None = None
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None


class Health(_Model):
    """``/healthz``: the process answers."""

    status: str


class Readiness(_Model):
    """``/readyz`` when ready (a service that is not answers 503, raised as :class:`~geoloc.client.ApiError`)."""

    status: Literal["ready", "not_ready"]
    profile: Literal["embedded", "distributed"]
    database: Literal["ok", "unreachable"]
    broker: Literal["ok", "unreachable"] | None = None
    schema_version: int
    expected_schema_version: int
    live_workers: int
    problems: list[str] = []


class License(_Model):
    """One row of the licence table."""

    name: str
    license: str
    source: str
    kind: Literal["model", "dataset", "map data", "dependency"]


class About(_Model):
    """``/v1/about``: the service's version and its licence table."""

    name: str
    version: str
    map_attribution_default: str
    licenses: list[License]


class Feature(_Model):
    """A GeoJSON feature (WGS84 lon/lat); ``properties`` as the API documents them per collection."""

    model_config = ConfigDict(extra="allow", frozen=True)

    type: Literal["Feature"]
    geometry: dict[str, Any] | None
    properties: dict[str, Any] | None = None


class FeatureCollection(_Model):
    """A GeoJSON FeatureCollection; foreign members (``attribution``, ``status``, ...) in ``model_extra``."""

    model_config = ConfigDict(extra="allow", frozen=True)

    type: Literal["FeatureCollection"]
    features: list[Feature]

    def member(self, name: str) -> Any:
        """A foreign member such as ``attribution`` or ``status`` (None when absent)."""
        return (self.model_extra or {}).get(name)
