"""Maps: upload (parsed by a ``load_map`` job in the workers), list, get, buildings and streets as GeoJSON, delete.

An upload is stored (after the size and decompressed-size checks) with a ``queued`` row and a job; the workers
parse it (:mod:`workers.map_handlers`), store its buildings and write the loaded map to ``DATA_DIR/cache/maps``
(:mod:`geoloc.maps.store`) so that other jobs start from that copy. The API never parses a map file: a request
holds a worker thread only to receive and check the upload, and waits (``wait_s``) on the event loop.
"""

from __future__ import annotations

import json
import logging
from typing import Annotated, Any

from fastapi import APIRouter, Depends, File, Form, Request, Response, UploadFile, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from contracts.answers import BoundingBox, LatLon
from contracts.api import MapList, MapOut, MapProgressOut
from contracts.licenses import map_attribution
from contracts.settings import Settings
from db import Database, database_key, transaction
from db import jobs as job_store
from db import maps as map_store
from db.files import FileStore
from db.rows import MapRow
from geoloc.maps import MapLoadError, MapReadOptions, map_cache_dir, remove_cached_map
from geoloc.maps.crs import parse_crs
from service.auth import Caller, request_caller, require_read, require_write
from service.bounds import MapId
from service.deps import app_settings, get_db, get_publisher, get_store, open_db
from service.errors import ApiError
from service.intake_maps import MapForm, MapUpload, accept_map
from service.reads import loaded_map, work_status
from service.responses import error_responses, timestamp
from service.tenancy import require_map, require_ready_map
from service.waiting import JobWaiter
from workers.broker import JobPublisher
from workers.sbow_files import remove_shared_base, sbow_cache_dir

log = logging.getLogger("geoloc.api")
router = APIRouter(prefix="/v1/maps", tags=["maps"])

MAX_MAP_WAIT_S = 600.0
"""The longest ``wait_s`` of a map upload."""
FILE_DESCRIPTION = (
    "The map, told by content: OSM XML (.osm, .osm.bz2, .osm.gz), .osm.pbf, GeoJSON (.geojson, .geojson.gz), "
    "GeoPackage (.gpkg), FlatGeobuf (.fgb) or a zipped Shapefile (.zip). GIS files in any CRS they declare "
    "(GeoJSON without one: WGS84 lon/lat); polygon features are the buildings."
)


def map_out(db: Database, row: MapRow, *, reference_count: int = 0, duplicate: bool = False) -> MapOut:
    """A map row as its API model; its status through :func:`service.reads.work_status` (row and job)."""
    job = job_store.get_job(db, row["job_id"]) if row["job_id"] is not None else None
    reported, error = work_status(row["status"], row["error"], job)
    return MapOut(
        id=row["id"],
        name=row["name"],
        status=reported,
        error=error,
        error_code=row["error_code"] if reported == "failed" and row["status"] == "failed" else None,
        error_details=row["error_details"] if reported == "failed" and row["status"] == "failed" else {},
        job_id=row["job_id"],
        progress=MapProgressOut(elements=row["parsed_elements"], buildings=row["parsed_buildings"]),
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


def map_form(
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
    wait_s: Annotated[
        float,
        Form(
            ge=0,
            le=MAX_MAP_WAIT_S,
            description="How long to wait for the parse before answering 202 (0: answer at once); within it, 201 "
            "with the map done, or 422 with the reason the file cannot be read",
        ),
    ] = 0.0,
) -> MapForm:
    """The map upload's form fields (but the file), as the upload route reads them (a dependency)."""
    return MapForm(name, layer, name_attribute, height_attribute, levels_attribute, crs, attribution, wait_s)


@router.post(
    "",
    response_model=MapOut,
    status_code=status.HTTP_201_CREATED,
    responses={
        200: {"model": MapOut, "description": "The same file was already uploaded"},
        202: {"model": MapOut, "description": "Stored and queued: poll GET /v1/maps/{id} until its status is done"},
        **error_responses(413, 422),
    },
    dependencies=[Depends(require_write)],
)
async def upload_map(
    request: Request,
    file: Annotated[UploadFile, File(description=FILE_DESCRIPTION)],
    form: Annotated[MapForm, Depends(map_form)],
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
    publisher: JobPublisher = Depends(get_publisher),
    caller: Caller = Depends(request_caller),
) -> MapOut | JSONResponse:
    """Upload a map: the file is stored and parsed into buildings and facades by a ``load_map`` job.

    202 with the map (``status`` ``queued``, its ``job_id`` and ``progress``): poll ``GET /v1/maps/{id}`` until
    its status is ``done`` (usable) or ``failed`` (``error`` says why); with ``wait_s``, 201 with the map done
    if the parse ends within it, or 422 with the reason (the failed map is then deleted: nothing is kept).
    200 with the existing map when the same file (sha256) was already uploaded with the same options
    (``duplicate: true``; a failed one does not count). 413 over the size limit, or when a compressed file
    (.gz, .bz2, .zip) inflates past ``GEOLOC_MAX_DECOMPRESSED_BYTES`` (counted before anything is stored);
    422 at once when the file is not map data by its content, or names an unknown CRS. Attribute defaults:
    ``name``, ``height``, ``building:levels``. ``attribution`` is not part of the duplicate check.
    """
    options = form.read_options()
    if options.crs is not None:
        try:
            parse_crs(options.crs)
        except MapLoadError as exc:
            raise ApiError(422, "invalid_request", f"crs: {exc}") from exc
    stated = form.attribution.strip() if form.attribution and form.attribution.strip() else None
    upload = MapUpload(file, form.name.strip(), options, stated, caller.tenant)
    accepted = await run_in_threadpool(accept_map, settings, store, publisher, upload)
    if accepted.duplicate:
        out = await run_in_threadpool(_map_model, settings, accepted.map_id, True, caller.tenant)
        return JSONResponse(out.model_dump(mode="json"), status_code=200)
    if accepted.job_id is not None and form.wait_s > 0:
        waiter: JobWaiter = request.app.state.job_waiter
        await waiter.wait(accepted.job_id, form.wait_s)
    out = await run_in_threadpool(_map_model, settings, accepted.map_id, False, caller.tenant)
    if out.status == "done":
        return JSONResponse(out.model_dump(mode="json"), status_code=201)
    if out.status == "failed" and form.wait_s > 0:  # answered now: nothing is kept, as when nothing was stored
        code, details = out.error_code or "invalid_map", out.error_details
        await run_in_threadpool(_delete_map, settings, store, accepted.map_id)
        raise ApiError(422, code, out.error or "the map file cannot be read", details or None)
    return JSONResponse(out.model_dump(mode="json"), status_code=202)


def _map_model(settings: Settings, map_id: int, duplicate: bool, tenant: str | None) -> MapOut:
    """The map's API model, read on a connection of its own (blocking: run in a worker thread)."""
    db = open_db(settings)
    try:
        row = require_map(db, map_id, tenant)
        return map_out(db, row, reference_count=_reference_total(db, map_id), duplicate=duplicate)
    finally:
        db.close()


def _reference_total(db: Database, map_id: int) -> int:
    return sum(map_store.map_reference_counts(db, map_id).values())


@router.get("", response_model=MapList, dependencies=[Depends(require_read)])
def list_maps(db: Database = Depends(get_db), caller: Caller = Depends(request_caller)) -> MapList:
    """The caller's maps (its key's tenant's; all untenanted ones for a key without a tenant), oldest first."""
    rows = map_store.list_maps(db, caller.tenant)
    return MapList(maps=[map_out(db, row, reference_count=_reference_total(db, row["id"])) for row in rows])


@router.get("/{map_id}", response_model=MapOut, responses=error_responses(404), dependencies=[Depends(require_read)])
def get_map(map_id: MapId, db: Database = Depends(get_db), caller: Caller = Depends(request_caller)) -> MapOut:
    """One map, with its ``status``.

    ``queued``, ``processing`` (its job runs; ``progress`` counts the parse), ``done`` (usable) or ``failed``
    (``error`` says why).
    """
    return map_out(db, require_map(db, map_id, caller.tenant), reference_count=_reference_total(db, map_id))


GEOJSON_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"content": {"application/geo+json": {}}, "description": "GeoJSON FeatureCollection"},
    **error_responses(404, 409),
}
"""The answers of a map's GeoJSON layers (buildings, streets)."""


@router.get(
    "/{map_id}/buildings",
    responses=GEOJSON_RESPONSES,
    response_class=Response,
    dependencies=[Depends(require_read)],
)
def get_buildings(map_id: MapId, db: Database = Depends(get_db), caller: Caller = Depends(request_caller)) -> Response:
    """The map's buildings as a GeoJSON FeatureCollection (WGS84, lon/lat), with the map's ``attribution``.

    409 while the map is not done. Each feature has its building id, OSM id, name and height.
    """
    attribution = json.dumps(map_attribution(require_ready_map(db, map_id, caller.tenant)["attribution"]))
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
    caller: Caller = Depends(request_caller),
) -> Response:
    """The map's streets as a GeoJSON FeatureCollection of LineStrings (WGS84, lon/lat), with ``attribution``.

    Each feature's properties: ``street_id`` (its index) and ``name`` (the OSM ``name`` tag, null when it has
    none). OSM maps' ``highway=*`` ways; GIS maps have no streets (an empty collection). 409 while the map is
    not done.
    """
    row = require_ready_map(db, map_id, caller.tenant)
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
    caller: Caller = Depends(request_caller),
) -> Response:
    """Delete a map with its buildings, references, labels, index entries and queries (also while it is parsed)."""
    require_map(db, map_id, caller.tenant)
    if not _delete_map(settings, store, map_id, db):
        raise ApiError(404, "not_found", f"map {map_id} not found")
    return Response(status_code=status.HTTP_204_NO_CONTENT)


def _delete_map(settings: Settings, store: FileStore, map_id: int, db: Database | None = None) -> bool:
    """Delete a map, its files and its finished parse job (a queued one is cancelled); False if there was none.

    Its files: the stored ones, the cached copy and the shared SBoW base. Blocking: run in a worker thread; on
    ``db``, or a connection of its own.
    """
    own = db is None
    db = open_db(settings) if db is None else db
    try:
        with transaction(db):
            deleted = map_store.delete_map(db, map_id)
        database = database_key(db)
    finally:
        if own:
            db.close()
    if deleted is None:
        return False
    remove_shared_base(sbow_cache_dir(settings.data_dir), database, map_id, deleted["created_at"])
    store.delete(*deleted["image_paths"])
    if not deleted["source_shared"]:  # the same file read with other options is another map
        store.delete(deleted["source_path"])
    remove_cached_map(
        map_cache_dir(settings.data_dir), deleted["sha256"], MapReadOptions.from_dict(deleted["read_options"])
    )
    store.remove_empty_folders(f"images/{map_id}", f"queries/{map_id}")
    return True
