"""Request/response models of the API (pydantic), with examples for the OpenAPI docs.

The parts that workers compute (query answers, reference labels) are in :mod:`contracts.answers`.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Literal, overload

from pydantic import BaseModel, ConfigDict, Field

from contracts.answers import BoundingBox, BuildingInPhoto, EstimatedPose, LatLon, QueryResult, TrackFrameResult
from contracts.jobs import WorkStatus
from service.errors import ERROR_CODES


@overload
def timestamp(value: float) -> datetime: ...
@overload
def timestamp(value: None) -> None: ...
def timestamp(value: float | None) -> datetime | None:
    """Unix seconds -> aware UTC datetime (None stays None)."""
    return datetime.fromtimestamp(value, tz=UTC) if value is not None else None


Attribution = Annotated[
    str,
    Field(
        description="The map data's attribution, to show with anything derived from the map: the map upload's "
        '`attribution` field, else "© OpenStreetMap contributors" (every format; docs/licenses.md)',
        examples=["© OpenStreetMap contributors"],
    ),
]
"""An answer's or a map's ``attribution`` (:func:`contracts.licenses.map_attribution`)."""


class ErrorDetail(BaseModel):
    """What went wrong: a machine-readable code, a message for people, and details."""

    code: str = Field(
        description="Machine-readable error code",
        examples=["outside_map"],
        json_schema_extra={
            # A list display (not sorted()'s list[str]) so that it types as a list of JSON values.
            "enum": [*sorted({code for _, code in ERROR_CODES})],
            "x-error-codes": [{"status": status, "code": code} for status, code in sorted(ERROR_CODES)],
        },
    )
    message: str = Field(description="What went wrong, for people", examples=["position is 5300 m outside the map"])
    details: dict[str, Any] | None = Field(default=None, description="Extra facts (limits, distances, fields)")


class ErrorResponse(BaseModel):
    """The body of every 4xx/5xx answer."""

    error: ErrorDetail


class MapProgressOut(BaseModel):
    """How far a map's parse got: elements read (OSM objects, GIS features) and buildings found so far."""

    elements: int = 0
    buildings: int = 0


class MapOut(BaseModel):
    """A stored map."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": 1,
                    "name": "helsinki-centre",
                    "status": "done",
                    "error": None,
                    "job_id": 12,
                    "progress": {"elements": 120000, "buildings": 464},
                    "source_filename": "helsinki.osm.pbf",
                    "source_format": "pbf",
                    "sha256": "9f2c...",
                    "bbox": {"min_lat": 60.1642, "min_lon": 24.9352, "max_lat": 60.1791, "max_lon": 24.9534},
                    "origin": {"lat": 60.1716, "lon": 24.9443},
                    "building_count": 464,
                    "facade_count": 6892,
                    "reference_count": 0,
                    "repair_report": {"format": "pbf", "closed_unclosed_ways": 1, "skipped_unclosed": 27},
                    "attribution": "© OpenStreetMap contributors",
                    "created_at": "2025-01-01T12:00:00Z",
                    "duplicate": False,
                }
            ]
        }
    )

    id: int
    name: str
    status: WorkStatus = Field(
        default="done",
        description="queued, processing (its job parses the file), done (usable) or failed (error says why); "
        "box, origin and counts are zeros until done",
    )
    error: str | None = Field(default=None, description="Why the map failed (or its job's last error)")
    error_code: str | None = Field(
        default=None, description="A failed map's machine reason, as a 422 of the upload gives it (invalid_map ...)"
    )
    error_details: dict[str, Any] = Field(default_factory=dict, description="The facts behind a failed map's error")
    job_id: int | None = Field(default=None, description="The load_map job that parses the file")
    progress: MapProgressOut = Field(default_factory=MapProgressOut, description="The parse's progress")
    source_filename: str
    source_format: str = Field(
        description="Detected from the content: osm, osm.bz2, osm.gz, pbf, geojson, geojson.gz, gpkg, fgb or "
        "shapefile.zip"
    )
    sha256: str
    bbox: BoundingBox
    origin: LatLon = Field(description="Origin of the map's local metric frame")
    building_count: int
    facade_count: int
    reference_count: int = 0
    repair_report: dict[str, Any] = Field(
        description="What the loader read (format, GIS layer, source CRS) and repaired or skipped, by kind"
    )
    read_options: dict[str, str] = Field(
        default_factory=dict,
        description="The upload's read options that differ from the defaults (layer, *_attribute, crs)",
    )
    attribution: Attribution
    created_at: datetime
    duplicate: bool = Field(
        default=False, description="True when this file was already uploaded with the same read options (same sha256)"
    )


class MapList(BaseModel):
    """The maps, oldest first."""

    maps: list[MapOut]


class JobOut(BaseModel):
    """A background job."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": 7,
                    "kind": "label_reference",
                    "status": "running",
                    "attempts": 1,
                    "max_attempts": 3,
                    "payload": {"reference_id": 3, "map_id": 1},
                    "result": None,
                    "error": None,
                    "created_at": "2025-01-01T12:00:00Z",
                    "updated_at": "2025-01-01T12:00:01Z",
                    "started_at": "2025-01-01T12:00:01Z",
                    "finished_at": None,
                }
            ]
        }
    )

    id: int
    kind: str
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    attempts: int
    max_attempts: int
    payload: dict[str, Any]
    result: dict[str, Any] | None = None
    error: str | None = Field(default=None, description="Last error with a traceback summary")
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None


class ReferenceAccepted(BaseModel):
    """Answer to a reference upload: the reference and the job that labels it."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"id": 3, "map_id": 1, "job_id": 7, "status": "queued", "sha256": "ab12...", "duplicate": False}
            ]
        }
    )

    id: int
    map_id: int
    job_id: int | None
    status: str
    sha256: str
    duplicate: bool = Field(
        default=False, description="True (HTTP 200) when this photo was already a reference of the map"
    )


class Position(BaseModel):
    """A WGS84 position (degrees) and where it came from."""

    lat: float = Field(examples=[60.1699])
    lon: float = Field(examples=[24.9384])
    source: Literal["exif", "request"] = Field(description="Where the position came from")


class ReferenceOut(BaseModel):
    """A reference photo and, once labelled, what the method found."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": 3,
                    "map_id": 1,
                    "status": "done",
                    "error": None,
                    "job_id": 7,
                    "sha256": "ab12...",
                    "original_filename": "IMG_0042.jpg",
                    "width": 4032,
                    "height": 3024,
                    "position": {"lat": 60.1699, "lon": 24.9384, "source": "exif"},
                    "prior_heading_deg": 84.0,
                    "prior_heading_accuracy_deg": 20.0,
                    "focal_length_35mm": 26.0,
                    "sequence_id": "walk-2025-01-01-a",
                    "capture_time": "2025-01-01T12:00:00.250+02:00",
                    "placement": "sequence",
                    "estimated": {"lat": 60.16992, "lon": 24.93851, "heading_deg": 87.0},
                    "buildings_seen": [
                        {
                            "building_id": 12,
                            "osm_id": "way/123",
                            "name": "Kiasma",
                            "pixel_share": 0.31,
                            "x_start": 0,
                            "x_end": 1830,
                            "probability": 0.82,
                        }
                    ],
                    "timings": {
                        "segmentation": 163.6,
                        "facades": 95.8,
                        "features": 55.7,
                        "labeling": 2504.1,
                        "total": 2840.2,
                    },
                    "attribution": "© OpenStreetMap contributors",
                    "created_at": "2025-01-01T12:00:00Z",
                    "updated_at": "2025-01-01T12:00:05Z",
                }
            ]
        }
    )

    id: int
    map_id: int
    status: Literal["queued", "processing", "done", "failed"]
    error: str | None = None
    job_id: int | None = None
    sha256: str
    original_filename: str | None = None
    width: int
    height: int
    position: Position
    prior_heading_deg: float | None = Field(
        default=None,
        description="Heading prior (deg clockwise from true north): the form's `heading_deg`, else the photo's compass",
    )
    prior_heading_accuracy_deg: float | None = Field(
        default=None,
        description=(
            "The compass's accuracy (deg) when the prior came from the photo's compass (a robust prior, see "
            "docs/method.md); null for a form heading, weighted as a plain 20 deg Gaussian"
        ),
    )
    focal_length_35mm: float | None = None
    sequence_id: str | None = Field(
        default=None,
        description="The walk it belongs to: the form's `sequence`, else the photo's Mapillary sequence id",
    )
    capture_time: str | None = Field(
        default=None,
        description="When it was taken (ISO 8601, as the photo states it: with an offset, or camera time)",
    )
    placement: Literal["alone", "sequence"] = Field(
        default="alone",
        description=(
            "`alone`: the pose is its own label's; `sequence`: its walk was placed jointly (docs/method.md), "
            "which replaces the label once the walk's references are labelled"
        ),
    )
    estimated: EstimatedPose | None = None
    buildings_seen: list[BuildingInPhoto] | None = None
    timings: dict[str, float] | None = None
    attribution: Attribution
    created_at: datetime
    updated_at: datetime


class Health(BaseModel):
    """Liveness: the process answers."""

    status: str = Field(examples=["ok"])


class Readiness(BaseModel):
    """What ``/readyz`` checked: the database, the broker (distributed profile), the models, live workers."""

    status: Literal["ready", "not_ready"]
    profile: Literal["embedded", "distributed"] = Field(
        description="`embedded` (SQLite, built-in workers) or `distributed` (PostgreSQL, Celery on Redis)"
    )
    database: Literal["ok", "unreachable"]
    broker: Literal["ok", "unreachable"] | None = Field(
        default=None, description="The Celery broker (Redis); null in the embedded profile, which has none"
    )
    schema_version: int
    expected_schema_version: int
    live_workers: int = Field(
        description="Worker processes that take queries and references (not those that only parse maps) with a "
        "heartbeat within `GEOLOC_READY_WORKER_S`"
    )
    problems: list[str] = Field(default_factory=list)


class QueryOut(BaseModel):
    """A query: its status and, when done, its answer."""

    id: int = Field(examples=[5])
    map_id: int = Field(examples=[1])
    status: Literal["queued", "processing", "done", "failed"]
    error: str | None = None
    job_id: int | None = Field(default=None, examples=[93])
    params: dict[str, Any] = Field(examples=[{"top_n": 10, "k": 4, "prior": {"lat": 60.1695, "lon": 24.9412}}])
    result: QueryResult | None = None
    attribution: Attribution
    created_at: datetime | None = None
    updated_at: datetime | None = None


class TrackOut(BaseModel):
    """A track: its status, its frames in order (each with its pose once located) and how it was searched."""

    id: int = Field(examples=[3])
    map_id: int = Field(examples=[1])
    status: Literal["queued", "processing", "done", "failed"]
    error: str | None = None
    job_id: int | None = Field(default=None, examples=[120])
    params: dict[str, Any] = Field(examples=[{"order": "sent", "top_n": 10, "k": 4, "preset": "balanced"}])
    frames: list[TrackFrameResult]
    search: dict[str, Any] | None = None
    timings_ms: dict[str, float] | None = None
    attribution: Attribution
    created_at: datetime | None = None
    updated_at: datetime | None = None


class ReferenceList(BaseModel):
    """One page of a map's references, oldest first, with the map's totals per status."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "map_id": 1,
                    "references": [],
                    "total": 60,
                    "counts": {"queued": 12, "processing": 2, "done": 45, "failed": 1},
                    "walks_placing": 1,
                    "next_after_id": 100,
                    "attribution": "© OpenStreetMap contributors",
                }
            ]
        }
    )

    map_id: int
    references: list[ReferenceOut] = Field(description="Up to `limit` references with ids above `after_id`, by id")
    total: int = Field(description="All references of the map")
    counts: dict[str, int] = Field(description="All references of the map per status: queued, processing, done, failed")
    walks_placing: int = Field(
        ge=0,
        description=(
            "Walk placements of this map queued or running (at most one waits and one runs). While above 0, "
            "the estimated poses of references in walks may still move (docs/method.md)"
        ),
    )
    next_after_id: int | None = Field(
        description="Pass as `after_id` for the next page; null on the last page", examples=[100]
    )
    attribution: Attribution


class LicenseOut(BaseModel):
    """One thing the service is built from and its licence (:data:`contracts.licenses.LICENSES`)."""

    name: str = Field(examples=["ALIKED keypoint weights (aliked-n16)"])
    license: str = Field(examples=["BSD-3-Clause"])
    source: str = Field(examples=["github.com/Shiaoming/ALIKED@683d7c6 (LICENSE, © 2022 Zhao Xiaoming)"])
    kind: Literal["model", "dataset", "map data", "dependency"]


class About(BaseModel):
    """The service's version and the licences of its models, data and main dependencies."""

    name: str = Field(examples=["geoloc"])
    version: str = Field(examples=["0.1.0"])
    map_attribution_default: str = Field(
        description="The attribution of a map whose upload states none", examples=["© OpenStreetMap contributors"]
    )
    licenses: list[LicenseOut]


def error_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route: each status answered with :class:`ErrorResponse`.

    Routes list the statuses their own code answers with; :mod:`service.spec` adds the ones that
    depend on the configuration or the request's form (auth, rate limit, multipart, full disk).
    """
    return {status: {"model": ErrorResponse} for status in statuses}
