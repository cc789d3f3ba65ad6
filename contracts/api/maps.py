"""Maps: ``POST/GET /v1/maps`` (:class:`MapOut`, :class:`MapList`) and ``GET /v1/maps/{id}/places``."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import ConfigDict, Field

from contracts.answers import BoundingBox, LatLon
from contracts.api.base import ApiModel, Attribution
from contracts.jobs import WorkStatus


class MapProgressOut(ApiModel):
    """How far a map's parse got: elements read (OSM objects, GIS features) and buildings found so far."""

    elements: int = 0
    buildings: int = 0


class MapOut(ApiModel):
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


class MapList(ApiModel):
    """The maps, oldest first."""

    maps: list[MapOut]


class PlaceOut(ApiModel):
    """A place of the map and the position prior it gives (WGS84 degrees; ``radius_m`` about 2 sigma)."""

    name: str = Field(examples=["Mannerheimintie 5"])
    kind: str = Field(description="address, building, street or landmark", examples=["address"])
    lat: float = Field(examples=[60.1695])
    lon: float = Field(examples=[24.94])
    radius_m: float = Field(
        description="The disc covering the place (m): the building plus a margin, the street's reach; the query's "
        "prior follows the place's shape (docs/places.md)"
    )
    building_id: int | None = Field(default=None, description="The map's building (addresses and buildings)")
    score: float = Field(description="How well the name matched the text (0-1, 1: exactly)")


class PlaceList(ApiModel):
    """Places matching a text, best first."""

    query: str
    places: list[PlaceOut]
