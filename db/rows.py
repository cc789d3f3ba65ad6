"""The rows ``db`` returns: one ``TypedDict`` per table that the API and the workers read.

Decision: rows are ``TypedDict``s, not dataclasses. A row stays the plain dict the driver gives (JSON columns
decoded), so the job API, logs and tests read it as before, and mypy checks every key and its type. Times are
Unix seconds; positions WGS84 degrees; headings degrees clockwise from north. ``total=True``: every column is
there (a column added by a migration exists in every row once the database is migrated).
"""

from __future__ import annotations

from typing import Any, Literal, TypedDict

from contracts.jobs import JobStatus
from contracts.queries import QueryParams


class MapRow(TypedDict):
    """A map (``maps``), decoded: ``repair_report`` and ``read_options`` as dicts, plus ``bbox_wgs84``."""

    id: int
    name: str
    source_filename: str
    source_format: str
    source_path: str
    sha256: str
    size_bytes: int
    min_lat: float
    min_lon: float
    max_lat: float
    max_lon: float
    origin_lat: float
    origin_lon: float
    building_count: int
    facade_count: int
    repair_report: dict[str, Any]
    read_options: dict[str, Any]
    attribution: str | None
    """The attribution the upload stated, None when it stated none (the default then applies)."""
    created_at: float
    tenant: str | None
    """The tenant of the key that uploaded it (migration 8); None: untenanted."""
    status: str
    """``queued`` (its ``load_map`` job waits or runs), ``done`` (usable) or ``failed`` (``error`` says why)."""
    error: str | None
    error_code: str | None
    error_details: dict[str, Any]
    """A failed map's machine reason (``invalid_map``, ``crs_not_lonlat`` ...) and the facts behind it."""
    job_id: int | None
    """The ``load_map`` job that parses it (None for a map stored before maps were jobs)."""
    parsed_elements: int
    parsed_buildings: int
    """The parse's progress: elements read and buildings found so far."""
    bbox_wgs84: tuple[float, float, float, float]
    """(min_lat, min_lon, max_lat, max_lon), from the four columns."""


class DeletedMap(MapRow):
    """A deleted map's row with what to remove after commit: its photos, and whether its source is shared."""

    image_paths: list[str]
    source_shared: bool


class ReferenceRow(TypedDict):
    """A reference photo (``reference_images``), its JSON columns decoded."""

    id: int
    map_id: int
    image_path: str
    original_filename: str | None
    sha256: str
    size_bytes: int
    image_format: str
    width: int
    height: int
    gps_lat: float
    gps_lon: float
    position_source: Literal["exif", "request"]
    prior_heading_deg: float | None
    prior_heading_accuracy_deg: float | None
    focal_length_35mm: float | None
    sequence_id: str | None
    capture_time: str | None
    device: str | None
    placement: Literal["alone", "sequence"]
    status: str
    job_id: int | None
    estimated_lat: float | None
    estimated_lon: float | None
    estimated_heading_deg: float | None
    buildings_seen: list[dict[str, Any]] | None
    timings: dict[str, float] | None
    error: str | None
    created_at: float
    updated_at: float


class QueryRow(TypedDict):
    """A query (``queries``): ``params`` as the :class:`contracts.queries.QueryParams` it was stored from."""

    id: int
    map_id: int
    image_path: str | None
    sha256: str | None
    params: QueryParams
    status: str
    job_id: int | None
    result: dict[str, Any] | None
    error: str | None
    created_at: float
    updated_at: float
    track_id: int | None
    """The track this query is a frame of (its photo and answer go with the track), None for a lone query."""
    frame_index: int | None


class TrackRow(TypedDict):
    """A track (``tracks``): ``params`` and ``result`` (a :class:`contracts.answers.TrackResult`) as JSON."""

    id: int
    map_id: int
    params: dict[str, Any]
    status: str
    job_id: int | None
    result: dict[str, Any] | None
    error: str | None
    created_at: float
    updated_at: float


class JobRow(TypedDict):
    """A job (``jobs``): ``payload`` and ``result`` decoded from their JSON (the handler's models read them)."""

    id: int
    kind: str
    payload: dict[str, Any]
    status: JobStatus
    priority: int
    attempts: int
    max_attempts: int
    run_after: float
    lease_owner: str | None
    lease_expires_at: float | None
    heartbeat_at: float | None
    map_id: int | None
    reference_id: int | None
    tenant: str | None
    """Stamped when queued (migration 8): the tenant given, else its map's; None: untenanted."""
    result: dict[str, Any] | None
    error: str | None
    created_at: float
    updated_at: float
    started_at: float | None
    finished_at: float | None
    published_at: float | None
    request_id: str | None
    """The API request that queued it (migration 12; a job queued by a job inherits its id); None before."""


class WorkerRow(TypedDict):
    """A worker process (``workers``): its liveness and current job."""

    worker_id: str
    pid: int
    hostname: str
    started_at: float
    heartbeat_at: float
    current_job_id: int | None
    stopped_at: float | None
    kinds: str | None  # the job kinds it claims, comma-separated; None: every kind
