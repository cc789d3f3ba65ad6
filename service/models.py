"""Request/response models of the API (pydantic), with examples for the OpenAPI docs."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


def timestamp(value: float | None) -> datetime | None:
    """Unix seconds -> aware UTC datetime (None stays None)."""
    return datetime.fromtimestamp(value, tz=UTC) if value is not None else None


class ErrorDetail(BaseModel):
    code: str = Field(description="Machine-readable error code", examples=["outside_map"])
    message: str = Field(description="What went wrong, for people", examples=["position is 5300 m outside the map"])
    details: dict[str, Any] | None = Field(default=None, description="Extra facts (limits, distances, fields)")


class ErrorResponse(BaseModel):
    """The body of every 4xx/5xx answer."""

    error: ErrorDetail


class BoundingBox(BaseModel):
    min_lat: float = Field(examples=[60.1641551])
    min_lon: float = Field(examples=[24.9351773])
    max_lat: float = Field(examples=[60.1791068])
    max_lon: float = Field(examples=[24.9534066])


class LatLon(BaseModel):
    lat: float = Field(examples=[60.1699])
    lon: float = Field(examples=[24.9384])


class MapOut(BaseModel):
    """A stored map."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": 1,
                    "name": "helsinki-centre",
                    "source_filename": "helsinki.osm.pbf",
                    "source_format": "pbf",
                    "sha256": "9f2c...",
                    "bbox": {"min_lat": 60.1642, "min_lon": 24.9352, "max_lat": 60.1791, "max_lon": 24.9534},
                    "origin": {"lat": 60.1716, "lon": 24.9443},
                    "building_count": 464,
                    "facade_count": 6892,
                    "reference_count": 0,
                    "repair_report": {"format": "pbf", "closed_unclosed_ways": 1, "skipped_unclosed": 27},
                    "created_at": "2025-01-01T12:00:00Z",
                    "duplicate": False,
                }
            ]
        }
    )

    id: int
    name: str
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
    created_at: datetime
    duplicate: bool = Field(
        default=False, description="True when this file was already uploaded with the same read options (same sha256)"
    )


class MapList(BaseModel):
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
    lat: float = Field(examples=[60.1699])
    lon: float = Field(examples=[24.9384])
    source: Literal["exif", "request"] = Field(description="Where the position came from")


class EstimatedPose(BaseModel):
    lat: float | None = None
    lon: float | None = None
    heading_deg: float | None = Field(default=None, description="Degrees clockwise from north")


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
                    "prior_heading_deg": None,
                    "focal_length_35mm": 26.0,
                    "estimated": {"lat": 60.16992, "lon": 24.93851, "heading_deg": 87.0},
                    "buildings_seen": [{"building_id": 12, "osm_id": "way/123", "name": "Kiasma", "pixel_share": 0.31}],
                    "timings": {"label_s": 4.2},
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
    prior_heading_deg: float | None = None
    focal_length_35mm: float | None = None
    estimated: EstimatedPose | None = None
    buildings_seen: list[dict[str, Any]] | None = None
    timings: dict[str, Any] | None = None
    created_at: datetime
    updated_at: datetime


class Health(BaseModel):
    status: str = Field(examples=["ok"])


class Readiness(BaseModel):
    status: Literal["ready", "not_ready"]
    schema_version: int
    expected_schema_version: int
    live_workers: int
    problems: list[str] = Field(default_factory=list)


class RankedLocation(BaseModel):
    """One answer: where the photo was taken and which way it looked."""

    rank: int = Field(examples=[1])
    lat: float = Field(examples=[60.16952])
    lon: float = Field(examples=[24.94117])
    heading_deg: float = Field(
        description="Compass heading of the optical axis, deg clockwise from north", examples=[93.0]
    )
    probability: float = Field(description="Probability of this position (summed over headings)", examples=[0.31])
    pose_probability: float = Field(description="Probability of this exact position and heading", examples=[0.12])


class Heatmap(BaseModel):
    """The probability map on its georeferenced grid (local east-north metres of the map's frame).

    ``values[row][col]`` is the probability of the cell centred at local
    (origin_local_m.x + col * cell_m, origin_local_m.y + row * cell_m): rows run south to north, columns
    west to east. ``origin`` is that first cell's centre in WGS84; ``bounds`` the grid's outer edges.
    """

    origin: LatLon
    origin_local_m: tuple[float, float] = Field(examples=[[-120.0, 40.0]])
    cell_m: float = Field(examples=[10.0])
    shape: tuple[int, int] = Field(description="(rows, cols)", examples=[[17, 21]])
    bounds: BoundingBox
    values: list[list[float]]


class BuildingInPhoto(BaseModel):
    """A building identified in the photo, with its horizontal pixel extent."""

    building_id: int = Field(examples=[212])
    osm_id: str | None = Field(examples=["way/8042381"])
    name: str | None = Field(examples=["Ateneum"])
    pixel_share: float = Field(description="Share of the photo's building pixels", examples=[0.46])
    x_start: int = Field(description="First pixel column (in the uploaded photo)", examples=[120])
    x_end: int = Field(description="Last pixel column", examples=[597])
    probability: float = Field(description="Mean identity probability over its columns", examples=[0.71])


class ReferenceUsed(BaseModel):
    """A retrieved reference and how well it matched."""

    reference_id: int = Field(examples=[17])
    score: float = Field(description="Retrieval (TF-IDF) score", examples=[0.23])
    matches: int = Field(examples=[85])
    inliers: int = Field(description="Geometrically verified matches", examples=[41])


class QueryResult(BaseModel):
    """The answer to a query photo."""

    locations: list[RankedLocation]
    heatmap: Heatmap
    buildings: list[BuildingInPhoto]
    references: list[ReferenceUsed]
    search: dict[str, Any] = Field(
        description="How the answer was searched: region, grid, whether identities and priors were used",
        examples=[{"region": "identified_buildings", "positions": 412, "yaws": 120, "identity": True}],
    )
    camera: dict[str, Any] = Field(
        description="The camera model used (field of view and where the focal length came from)",
        examples=[{"hfov_deg": 63.4, "focal_source": "exif_35mm", "width": 1024, "height": 768}],
    )
    timings_ms: dict[str, float]


class QueryOut(BaseModel):
    """A query: its status and, when done, its answer."""

    id: int = Field(examples=[5])
    map_id: int = Field(examples=[1])
    status: Literal["queued", "processing", "done", "failed"]
    error: str | None = None
    job_id: int | None = Field(default=None, examples=[93])
    params: dict[str, Any] = Field(examples=[{"top_n": 10, "k": 4, "prior": {"lat": 60.1695, "lon": 24.9412}}])
    result: QueryResult | None = None
    created_at: datetime | None = None
    updated_at: datetime | None = None
