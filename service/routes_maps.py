"""Maps: upload (loaded with ``geoloc.maps.load_map``), list, get, buildings and streets as GeoJSON, delete.

An upload is read once, in the API process; its buildings become rows and the loaded map is also
written to ``DATA_DIR/cache/maps`` (:mod:`geoloc.maps.store`) so that workers start from that copy
instead of parsing the source again (they rebuild it from the source if it is missing).
"""

from __future__ import annotations

import json
import logging
from typing import Annotated, Any

from fastapi import APIRouter, Depends, File, Form, Response, UploadFile, status
from fastapi.responses import JSONResponse

from contracts.answers import BoundingBox, LatLon
from contracts.licenses import map_attribution
from contracts.settings import Settings
from db import Database, transaction
from db import maps as map_store
from db.files import FileStore
from db.rows import MapRow
from geoloc.maps import (
    MapLoadError,
    MapReadOptions,
    load_map,
    map_cache_dir,
    map_cache_path,
    remove_cached_map,
    save_city_map,
)
from geoloc.maps.crs import parse_crs
from geoloc.maps.guard import DecompressedTooLargeError, check_decompressed_size, public_message, public_name
from service.auth import require_read, require_write
from service.bounds import MapId
from service.deps import app_settings, get_db, get_store
from service.errors import ApiError
from service.intake import loaded_map, require_map
from service.models import MapList, MapOut, error_responses, timestamp
from service.uploads import received_upload

log = logging.getLogger("geoloc.api")
router = APIRouter(prefix="/v1/maps", tags=["maps"])

SOURCE_EXTENSIONS = {
    "osm": ".osm",
    "osm.bz2": ".osm.bz2",
    "osm.gz": ".osm.gz",
    "pbf": ".osm.pbf",
    "geojson": ".geojson",
    "geojson.gz": ".geojson.gz",
    "gpkg": ".gpkg",
    "fgb": ".fgb",
    "shapefile.zip": ".zip",
}
FILE_DESCRIPTION = (
    "The map, told by content: OSM XML (.osm, .osm.bz2, .osm.gz), .osm.pbf, GeoJSON (.geojson, .geojson.gz), "
    "GeoPackage (.gpkg), FlatGeobuf (.fgb) or a zipped Shapefile (.zip). GIS files in any CRS they declare "
    "(GeoJSON without one: WGS84 lon/lat); polygon features are the buildings."
)


def map_out(row: MapRow, *, reference_count: int = 0, duplicate: bool = False) -> MapOut:
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
        read_options=row["read_options"],
        attribution=map_attribution(row["attribution"]),
        created_at=timestamp(row["created_at"]),
        duplicate=duplicate,
    )


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
    file: Annotated[UploadFile, File(description=FILE_DESCRIPTION)],
    name: Annotated[
        str, Form(min_length=1, max_length=200, pattern=r"\S", description="A name for the map (not blank)")
    ],
    layer: Annotated[
        str | None,
        Form(
            max_length=200,
            description="GIS files: the layer to read (a GeoPackage table, a shapefile's name in the zip); "
            "needed only when the file has several polygon layers and not exactly one is named buildings "
            "(else has a building attribute)",
        ),
    ] = None,
    name_attribute: Annotated[
        str | None, Form(max_length=200, description="Attribute (GIS field or OSM tag) with the building's name")
    ] = None,
    height_attribute: Annotated[
        str | None, Form(max_length=200, description="Attribute with the building's height in metres")
    ] = None,
    levels_attribute: Annotated[
        str | None,
        Form(max_length=200, description="Attribute with the building's number of storeys (x 3 m)"),
    ] = None,
    crs: Annotated[
        str | None,
        Form(
            max_length=2000,
            description="GIS files: the CRS of the coordinates (e.g. EPSG:3857), overriding what the file "
            "declares; for files that declare none and are not WGS84 lon/lat",
        ),
    ] = None,
    attribution: Annotated[
        str | None,
        Form(
            max_length=500,
            description="The map data's attribution as its licence requires it shown (e.g. a GIS source's "
            '"© City of Helsinki, CC BY 4.0"); default "© OpenStreetMap contributors". Returned with the map '
            "and every answer on it",
        ),
    ] = None,
    db: Database = Depends(get_db),
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
) -> MapOut | JSONResponse:
    """Upload a map: buildings and facades are extracted and stored.

    Attribute defaults: ``name``, ``height``, ``building:levels``. 201 with the new map; 200 with the
    existing map when the same file (sha256) was already uploaded with the same options
    (``duplicate: true``); 413 over the size limit, or when a compressed file (.gz, .bz2, .zip) inflates past
    ``GEOLOC_MAX_DECOMPRESSED_BYTES`` (counted before anything is parsed or stored); 422 when the file is not
    map data, holds no usable buildings, names a layer or attribute it does not have, or has coordinates that
    cannot be placed (the message says which CRS they look like and how to fix it). ``attribution`` is not part of the
    duplicate check: the same file sent again gets the existing map with the attribution it was stored with.
    """
    options = _read_options(layer, name_attribute, height_attribute, levels_attribute, crs)
    if options.crs is not None:
        try:
            parse_crs(options.crs)
        except MapLoadError as exc:
            raise ApiError(422, "invalid_request", f"crs: {exc}") from exc
    read_options = options.as_dict()
    with received_upload(file, store, settings.max_map_bytes, "the map file") as received:
        existing = map_store.find_map_by_sha256(db, received.sha256, read_options)
        if existing is not None:
            out = map_out(existing, reference_count=_reference_total(db, existing["id"]), duplicate=True)
            return JSONResponse(out.model_dump(mode="json"), status_code=200)
        shown_name = public_name(received.filename)
        try:
            check_decompressed_size(received.path, settings.max_decompressed_bytes, shown_name)
        except DecompressedTooLargeError as exc:
            raise ApiError(413, exc.code, str(exc), exc.details) from exc
        try:
            city_map = load_map(received.path, options)
            content = map_store.map_content_from_city_map(city_map)
        except MapLoadError as exc:
            raise ApiError(422, exc.code, public_message(str(exc), received.path, shown_name), exc.details) from exc
        except Exception as exc:  # the file made a library fail in a way not foreseen: still the file's fault
            log.exception("map upload %s could not be read", shown_name)
            reason = public_message(f"{type(exc).__name__}: {exc}", received.path, shown_name)
            raise ApiError(422, "invalid_map", f"{shown_name}: cannot read the map ({reason})") from exc
        source_format = city_map.report.format
        relative = f"maps/{received.sha256}{SOURCE_EXTENSIONS.get(source_format, '.map')}"
        with transaction(db):  # the duplicate check and the insert are atomic
            db.lock(f"geoloc:map:{received.sha256}")  # the same file sent twice at once
            existing = map_store.find_map_by_sha256(db, received.sha256, read_options)
            if existing is None:
                received.move_to(relative)
                map_id = map_store.insert_map(
                    db,
                    name=name.strip(),
                    source_filename=received.filename or "upload",
                    source_format=source_format,
                    source_path=relative,
                    sha256=received.sha256,
                    size_bytes=received.size_bytes,
                    content=content,
                    read_options=read_options,
                    attribution=attribution.strip() if attribution and attribution.strip() else None,
                )
        if existing is not None:
            out = map_out(existing, reference_count=_reference_total(db, existing["id"]), duplicate=True)
            return JSONResponse(out.model_dump(mode="json"), status_code=200)
    try:  # a cache: the workers rebuild it from the source if this fails
        save_city_map(city_map, map_cache_path(map_cache_dir(settings.data_dir), received.sha256, options))
    except OSError:
        log.warning("map %d: could not write its cached copy", map_id, exc_info=True)
    log.info("map %d stored: %d buildings, %d facades", map_id, len(content.buildings), len(city_map.facades))
    row = map_store.get_map(db, map_id)
    assert row is not None
    return map_out(row)


def _read_options(
    layer: str | None,
    name_attribute: str | None,
    height_attribute: str | None,
    levels_attribute: str | None,
    crs: str | None,
) -> MapReadOptions:
    """The form fields as ``MapReadOptions`` (blank fields mean the default)."""
    given = {
        "layer": layer,
        "name_attribute": name_attribute,
        "height_attribute": height_attribute,
        "levels_attribute": levels_attribute,
        "crs": crs,
    }
    return MapReadOptions(**{k: v.strip() for k, v in given.items() if v is not None and v.strip()})


def _reference_total(db: Database, map_id: int) -> int:
    return sum(map_store.map_reference_counts(db, map_id).values())


@router.get("", response_model=MapList, dependencies=[Depends(require_read)])
def list_maps(db: Database = Depends(get_db)) -> MapList:
    """All maps, oldest first."""
    return MapList(
        maps=[map_out(row, reference_count=_reference_total(db, row["id"])) for row in map_store.list_maps(db)]
    )


@router.get("/{map_id}", response_model=MapOut, responses=error_responses(404), dependencies=[Depends(require_read)])
def get_map(map_id: MapId, db: Database = Depends(get_db)) -> MapOut:
    """One map."""
    return map_out(require_map(db, map_id), reference_count=_reference_total(db, map_id))


GEOJSON_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"content": {"application/geo+json": {}}, "description": "GeoJSON FeatureCollection"},
    **error_responses(404),
}
"""The answers of a map's GeoJSON layers (buildings, streets)."""


@router.get(
    "/{map_id}/buildings",
    responses=GEOJSON_RESPONSES,
    response_class=Response,
    dependencies=[Depends(require_read)],
)
def get_buildings(map_id: MapId, db: Database = Depends(get_db)) -> Response:
    """The map's buildings as a GeoJSON FeatureCollection (WGS84, lon/lat), with the map's ``attribution``.

    Each feature has its building id, OSM id, name and height.
    """
    attribution = json.dumps(map_attribution(require_map(db, map_id)["attribution"]))
    # The stored geometry text goes out as it is: no decoding and re-encoding of a city's footprints.
    features = ",".join(
        f'{{"type":"Feature","id":{b["building_id"]},"geometry":{b["footprint_geojson"]},"properties":'
        + json.dumps({k: b[k] for k in ("building_id", "osm_id", "name", "height_m")})
        + "}"
        for b in map_store.list_buildings(db, map_id, decode=False)
    )
    body = '{"type":"FeatureCollection","attribution":' + attribution + ',"features":[' + features + "]}"
    return Response(body, media_type="application/geo+json")


@router.get(
    "/{map_id}/streets",
    responses=GEOJSON_RESPONSES,
    response_class=Response,
    dependencies=[Depends(require_read)],
)
def get_streets(
    map_id: MapId,
    db: Database = Depends(get_db),
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
) -> Response:
    """The map's streets as a GeoJSON FeatureCollection of LineStrings (WGS84, lon/lat), with ``attribution``.

    Each feature's properties: ``street_id`` (its index) and ``name`` (the OSM ``name`` tag, null when it has
    none). OSM maps' ``highway=*`` ways; GIS maps have no streets (an empty collection).
    """
    row = require_map(db, map_id)
    city_map = loaded_map(settings, store, row)
    bounds = city_map.street_offsets.tolist()
    names = city_map.street_names or [""] * (len(bounds) - 1)  # "" is an unnamed street
    features = [
        {
            "type": "Feature",
            "id": i,
            "geometry": {"type": "LineString", "coordinates": city_map.street_lonlat[a:b].round(7).tolist()},
            "properties": {"street_id": i, "name": name or None},
        }
        for i, (a, b, name) in enumerate(zip(bounds[:-1], bounds[1:], names, strict=True))
    ]
    body = {"type": "FeatureCollection", "attribution": map_attribution(row["attribution"]), "features": features}
    return Response(json.dumps(body, separators=(",", ":")), media_type="application/geo+json")


@router.delete(
    "/{map_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=error_responses(404),
    dependencies=[Depends(require_write)],
)
def delete_map(
    map_id: MapId,
    db: Database = Depends(get_db),
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
) -> Response:
    """Delete a map with its buildings, references, labels, index entries and queries."""
    with transaction(db):
        deleted = map_store.delete_map(db, map_id)
    if deleted is None:
        raise ApiError(404, "not_found", f"map {map_id} not found")
    store.delete(*deleted["image_paths"])
    if not deleted["source_shared"]:  # the same file read with other options is another map
        store.delete(deleted["source_path"])
    remove_cached_map(
        map_cache_dir(settings.data_dir), deleted["sha256"], MapReadOptions.from_dict(deleted["read_options"])
    )
    store.remove_empty_folders(f"images/{map_id}", f"queries/{map_id}")
    return Response(status_code=status.HTTP_204_NO_CONTENT)
