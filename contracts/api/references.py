"""References: ``POST /v1/maps/{id}/references``, ``GET /v1/references/{id}`` and a map's page of references."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import ConfigDict, Field

from contracts.answers import BuildingInPhoto, EstimatedPose
from contracts.api.base import ApiModel, Attribution
from contracts.jobs import WorkStatus


class ReferenceAccepted(ApiModel):
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


class Position(ApiModel):
    """A WGS84 position (degrees) and where it came from."""

    lat: float = Field(examples=[60.1699])
    lon: float = Field(examples=[24.9384])
    source: Literal["exif", "request"] = Field(description="Where the position came from")


class ReferenceOut(ApiModel):
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
    status: WorkStatus
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


class ReferenceList(ApiModel):
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
