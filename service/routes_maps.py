"""Maps: upload (loaded with ``geoloc.osm.load_map``), list, get, buildings as GeoJSON, delete."""

from __future__ import annotations

import contextlib
import logging
from typing import Annotated, Any

import sqlite_utils
from fastapi import APIRouter, Depends, File, Form, Response, UploadFile, status
from fastapi.responses import JSONResponse

from db import maps as map_store
from db import transaction
from service.auth import require_read, require_write
from service.bounds import MapId
from service.deps import get_db, get_settings
from service.errors import ApiError
from service.models import BoundingBox, LatLon, MapList, MapOut, error_responses, timestamp
from service.settings import Settings
from service.uploads import received_upload, remove_quietly

log = logging.getLogger("geoloc.api")
router = APIRouter(prefix="/v1/maps", tags=["maps"])

SOURCE_EXTENSIONS = {"osm": ".osm", "osm.bz2": ".osm.bz2", "pbf": ".osm.pbf", "geojson": ".geojson"}


def map_out(row: dict[str, Any], *, reference_count: int = 0, duplicate: bool = False) -> MapOut:
    """A map row as its API model."""
    return MapOut(
        id=row["id"],
        name=row["name"],
        source_filename=row["source_filename"],
        source_format=row["source_format"],
        sha256=row["sha256"],
        bbox=BoundingBox(
            min_lat=row["min_lat"], min_lon=row["min_lon"], max_lat=row["max_lat"], max_lon=row["max_lon"]
        ),
        origin=LatLon(lat=row["origin_lat"], lon=row["origin_lon"]),
        building_count=row["building_count"],
        facade_count=row["facade_count"],
        reference_count=reference_count,
        repair_report=row["repair_report"],
        created_at=timestamp(row["created_at"]),
        duplicate=duplicate,
    )


def require_map(db: sqlite_utils.Database, map_id: int) -> dict[str, Any]:
    """The map row, or 404."""
    row = map_store.get_map(db, map_id)
    if row is None:
        raise ApiError(404, "not_found", f"map {map_id} not found")
    return row


@router.post(
    "",
    response_model=MapOut,
    status_code=status.HTTP_201_CREATED,
    responses={
        200: {"model": MapOut, "description": "The same file was already uploaded"},
        **error_responses(413, 422),
    },
    dependencies=[Depends(require_write)],
)
def upload_map(
    file: Annotated[UploadFile, File(description="OSM XML (.osm), .osm.bz2, .osm.pbf or GeoJSON; checked by content")],
    name: Annotated[
        str, Form(min_length=1, max_length=200, pattern=r"\S", description="A name for the map (not blank)")
    ],
    db: sqlite_utils.Database = Depends(get_db),
    settings: Settings = Depends(get_settings),
) -> MapOut | JSONResponse:
    """Upload a map: buildings and facades are extracted and stored.

    201 with the new map; 200 with the existing map when a file with the same sha256 was already
    uploaded (``duplicate: true``); 413 over the size limit; 422 when the file is not map data or
    holds no usable buildings.
    """
    from geoloc.osm import MapLoadError, load_map

    with received_upload(file, settings.data_dir, settings.max_map_bytes, "the map file") as received:
        existing = map_store.find_map_by_sha256(db, received.sha256)
        if existing is not None:
            out = map_out(existing, reference_count=_reference_total(db, existing["id"]), duplicate=True)
            return JSONResponse(out.model_dump(mode="json"), status_code=200)
        try:
            city_map = load_map(received.path)
        except MapLoadError as exc:
            message = str(exc).replace(received.path.name, received.filename or "the file")
            raise ApiError(422, "invalid_map", message) from exc
        content = map_store.map_content_from_city_map(city_map)
        source_format = city_map.report.format
        relative = f"maps/{received.sha256}{SOURCE_EXTENSIONS.get(source_format, '.map')}"
        final_path = settings.data_dir / relative
        with transaction(db):  # BEGIN IMMEDIATE: the duplicate check and the insert are atomic
            existing = map_store.find_map_by_sha256(db, received.sha256)
            if existing is None:
                received.move_to(final_path)
                map_id = map_store.insert_map(
                    db,
                    name=name.strip(),
                    source_filename=received.filename or "upload",
                    source_format=source_format,
                    source_path=relative,
                    sha256=received.sha256,
                    size_bytes=received.size_bytes,
                    content=content,
                )
        if existing is not None:
            out = map_out(existing, reference_count=_reference_total(db, existing["id"]), duplicate=True)
            return JSONResponse(out.model_dump(mode="json"), status_code=200)
    log.info("map %d stored: %d buildings, %d facades", map_id, len(content.buildings), len(city_map.facades))
    row = map_store.get_map(db, map_id)
    assert row is not None
    return map_out(row)


def _reference_total(db: sqlite_utils.Database, map_id: int) -> int:
    return sum(map_store.map_reference_counts(db, map_id).values())


@router.get("", response_model=MapList, dependencies=[Depends(require_read)])
def list_maps(db: sqlite_utils.Database = Depends(get_db)) -> MapList:
    """All maps, oldest first."""
    return MapList(
        maps=[map_out(row, reference_count=_reference_total(db, row["id"])) for row in map_store.list_maps(db)]
    )


@router.get("/{map_id}", response_model=MapOut, responses=error_responses(404), dependencies=[Depends(require_read)])
def get_map(map_id: MapId, db: sqlite_utils.Database = Depends(get_db)) -> MapOut:
    """One map."""
    return map_out(require_map(db, map_id), reference_count=_reference_total(db, map_id))


@router.get(
    "/{map_id}/buildings",
    responses={
        200: {"content": {"application/geo+json": {}}, "description": "GeoJSON FeatureCollection"},
        **error_responses(404),
    },
    dependencies=[Depends(require_read)],
)
def get_buildings(map_id: MapId, db: sqlite_utils.Database = Depends(get_db)) -> JSONResponse:
    """The map's buildings as a GeoJSON FeatureCollection (WGS84, lon/lat) with building id, OSM id,
    name and height."""
    require_map(db, map_id)
    features = [
        {
            "type": "Feature",
            "id": b["building_id"],
            "geometry": b["footprint_geojson"],
            "properties": {
                "building_id": b["building_id"],
                "osm_id": b["osm_id"],
                "name": b["name"],
                "height_m": b["height_m"],
            },
        }
        for b in map_store.list_buildings(db, map_id)
    ]
    return JSONResponse({"type": "FeatureCollection", "features": features}, media_type="application/geo+json")


@router.delete(
    "/{map_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=error_responses(404),
    dependencies=[Depends(require_write)],
)
def delete_map(
    map_id: MapId, db: sqlite_utils.Database = Depends(get_db), settings: Settings = Depends(get_settings)
) -> Response:
    """Delete a map with its buildings, references, labels, index entries and queries."""
    with transaction(db):
        deleted = map_store.delete_map(db, map_id)
    if deleted is None:
        raise ApiError(404, "not_found", f"map {map_id} not found")
    remove_quietly(*(settings.data_dir / p for p in deleted["image_paths"]), settings.data_dir / deleted["source_path"])
    for folder in (settings.data_dir / "images" / str(map_id), settings.data_dir / "queries" / str(map_id)):
        with contextlib.suppress(OSError):
            folder.rmdir()
    return Response(status_code=status.HTTP_204_NO_CONTENT)
