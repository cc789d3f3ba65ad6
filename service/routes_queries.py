"""Queries: where was this photo taken? Answered by the ``localize_query`` job in the worker pool.

``POST /v1/maps/{id}/queries`` stores the photo, queues the job and waits up to ``wait_s`` seconds
for the answer (200 with the result); a slower answer comes back as 202 with the query id to poll
(``GET /v1/queries/{id}``). Heavy work (segmentation, matching, the likelihood) runs in workers only.

The wait holds no thread: the request awaits its job on the event loop (:mod:`service.waiting`), so
any number of clients can wait while reads are served. ``GET /v1/queries/{id}?wait_s=N`` waits the same
way (a long poll). Storing the photo and the job runs in a worker
thread for the few milliseconds it takes. While the job queue is full the request gets ``429`` with
``Retry-After`` and nothing is stored (:mod:`service.limits`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Annotated, Any

from fastapi import APIRouter, Depends, File, Form, Query, Request, Response, UploadFile, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse

from contracts.answers import QueryResult
from contracts.api import QueryOut
from contracts.licenses import map_attribution
from contracts.queries import QueryPreset
from contracts.settings import Settings
from db import Database
from db import jobs as job_store
from db import maps as map_store
from db import queries as query_store
from db.files import FileStore
from db.rows import JobRow, QueryRow
from service.auth import Caller, request_caller, require_read, require_write
from service.bounds import MapId, QueryId, bounded_form
from service.deps import app_settings, get_db, get_publisher, get_store, open_db
from service.errors import ApiError
from service.geojson import (
    GEOJSON_MEDIA_TYPE,
    GEOJSON_RESPONSE,
    GeoJsonFormat,
    pose_points,
    query_collection,
    wants_geojson,
)
from service.heatmap_png import heatmap_png
from service.images import ACCEPTED_NAMES, STORED_MEDIA_TYPES, stored_photo_response
from service.intake_queries import QueryForm, QueryIntake
from service.limits import require_queue_capacity
from service.photo_deletion import delete_with_photos
from service.reads import READ_ERRORS, loaded_map, work_status
from service.responses import error_responses, timestamp
from service.spec import QUEUE_FULL_RESPONSE
from service.tenancy import require_map, require_query
from service.waiting import answered, long_poll
from workers.broker import JobPublisher

router = APIRouter(tags=["queries"])


def query_out(row: QueryRow, job: JobRow | None, attribution: str) -> QueryOut:
    """A query row (and its job) as its API model, with its map's ``attribution``."""
    state, error = work_status(row["status"], row["error"], job)
    return QueryOut(
        id=row["id"],
        map_id=row["map_id"],
        status=state,
        error=error,
        job_id=row["job_id"],
        params=row["params"].to_json(),
        result=None if row["result"] is None else QueryResult.model_validate(row["result"]),
        attribution=attribution,
        created_at=timestamp(row["created_at"]),
        updated_at=timestamp(row["updated_at"]),
    )


def _load(db: Database, query_id: int, tenant: str | None) -> tuple[QueryRow, JobRow | None]:
    row = require_query(db, query_id, tenant)
    job = job_store.get_job(db, row["job_id"]) if row["job_id"] else None
    return row, job


def _attribution(db: Database, map_id: int) -> str:
    row = map_store.get_map(db, map_id)
    return map_attribution(None if row is None else row["attribution"])


def _load_query(
    settings: Settings, query_id: int, tenant: str | None, *, geojson: bool = False
) -> QueryOut | dict[str, Any]:
    """The query (of ``tenant``, else 404) as its API model, or with ``geojson`` as its FeatureCollection.

    The FeatureCollection is :mod:`service.geojson`'s.
    """
    db = open_db(settings)
    try:
        row, job = _load(db, query_id, tenant)
        out = query_out(row, job, _attribution(db, row["map_id"]))
        if not geojson:
            return out
        wanted = [b.building_id for b in out.result.buildings] if out.result else []
        buildings = map_store.list_buildings(db, row["map_id"], building_ids=wanted) if wanted else []
        return query_collection(out, {b["building_id"]: b["footprint_geojson"] for b in buildings})
    finally:
        db.close()


def _query_model(settings: Settings, query_id: int, tenant: str | None) -> QueryOut:
    out = _load_query(settings, query_id, tenant)
    assert isinstance(out, QueryOut)
    return out


@dataclass(frozen=True)
class AnswerFields:
    """The form fields of a query that shape its answer and the wait for it (:func:`answer_fields`)."""

    top_n: int
    k: int
    wait_s: float
    preset: QueryPreset | None


def answer_fields(
    top_n: Annotated[int, bounded_form("top_n", "How many distinct locations to return")] = 10,
    k: Annotated[int, bounded_form("k", "How many references to retrieve for identities")] = 4,
    wait_s: Annotated[float, bounded_form("wait_s", "How long to wait for the answer before 202")] = 60.0,
    preset: Annotated[
        QueryPreset | None,
        Form(description="Speed against accuracy: fast, balanced or accurate (default GEOLOC_QUERY_PRESET)"),
    ] = None,
) -> AnswerFields:
    """The query form's answer fields, as the upload route reads them (a dependency: the form's second half)."""
    return AnswerFields(top_n, k, wait_s, preset)


def query_form(
    lat: Annotated[float | None, bounded_form("lat", "Prior position latitude (WGS84)")] = None,
    lon: Annotated[float | None, bounded_form("lon", "Prior position longitude (WGS84)")] = None,
    radius_m: Annotated[
        float | None,
        bounded_form(
            "radius_m",
            "Prior position radius (m, about 2 sigma). Default: 50 with lat/lon; the place's with a place; with "
            "EXIF GPS twice the accuracy the photo states (GPSHPositioningError, else Mapillary's "
            "MAPGPSAccuracyMeters; at least 10), 50 when it states none",
        ),
    ] = None,
    heading_deg: Annotated[float | None, bounded_form("heading_deg", "Prior heading, deg clockwise from north")] = None,
    use_exif_gps: Annotated[bool, Form(description="Use the photo's EXIF GPS as the prior position")] = True,
    place: Annotated[
        str | None,
        Form(
            description="A place of the map as the prior position: a building's name, an address, a street "
            "(GET /v1/maps/{id}/places); overrides EXIF GPS, not with lat/lon",
            max_length=200,
        ),
    ] = None,
    focal_length_35mm: Annotated[
        float | None, bounded_form("focal_length_35mm", "35 mm-equivalent focal length")
    ] = None,
    *,
    answer: Annotated[AnswerFields, Depends(answer_fields)],
) -> QueryForm:
    """The query form, as the upload route reads it: the prior fields, then the answer's (the documented order)."""
    return QueryForm(
        lat, lon, radius_m, heading_deg, use_exif_gps, place, focal_length_35mm,
        answer.top_n, answer.k, answer.wait_s, answer.preset,
    )  # fmt: skip


@router.post(
    "/v1/maps/{map_id}/queries",
    response_model=QueryOut,
    responses={
        202: {"model": QueryOut, "description": "Not answered within wait_s: poll the query"},
        **error_responses(404, 413, 415, 422),
        **QUEUE_FULL_RESPONSE,
    },
    dependencies=[Depends(require_read), Depends(require_queue_capacity)],
)
async def create_query(
    request: Request,
    map_id: MapId,
    image: Annotated[UploadFile, File(description=f"The photo to geolocate ({ACCEPTED_NAMES}; checked by content)")],
    form: Annotated[QueryForm, Depends(query_form)],
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
    publisher: JobPublisher = Depends(get_publisher),
    caller: Caller = Depends(request_caller),
) -> QueryOut | JSONResponse:
    """Geolocate a photo on a map: ranked locations with headings, the heatmap, the buildings in the photo.

    A prior position (``lat``/``lon`` with ``radius_m``; else a ``place`` named in the map, the prior along
    its footprint or street (``radius_m``, when given, the distance from it), 422 ``ambiguous_place`` with
    candidates or ``unknown_place``; else
    the photo's EXIF GPS unless ``use_exif_gps`` is false, its radius from the accuracy the photo states) and a
    prior heading (``heading_deg``, else the
    photo's compass with its accuracy as a robust prior: Mapillary's JSON, else EXIF GPSImgDirection) are
    used as priors and reported in ``result.search``. ``preset`` picks the query stage's configuration (fast,
    balanced, accurate; stored in ``params.preset``, the answer's ``search.preset`` and ``search.config``).
    200 with the answer, or 202 if it took longer than ``wait_s``; 429 while the job queue is full (retry after
    ``Retry-After`` seconds). A panorama is a 422 ``unsupported_projection`` (only perspective photos are
    supported).
    """
    intake = QueryIntake(settings, store, publisher, form)
    accepted = await run_in_threadpool(intake.accept, map_id, image, caller.tenant)
    assert accepted.job_id is not None  # a query is never a duplicate
    return await answered(
        request, accepted.job_id, form.wait_s, partial(_query_model, settings, accepted.subject_id, caller.tenant)
    )


@router.get(
    "/v1/queries/{query_id}",
    response_model=QueryOut,
    responses={200: {"content": GEOJSON_RESPONSE}, **error_responses(404)},
    dependencies=[Depends(require_read)],
)
async def get_query(
    request: Request,
    query_id: QueryId,
    wait_s: Annotated[
        float,
        Query(ge=0, le=300, description="Wait up to this long for the answer if it is not ready (a long poll)"),
    ] = 0.0,
    format_name: GeoJsonFormat = None,
    settings: Settings = Depends(app_settings),
    caller: Caller = Depends(request_caller),
) -> QueryOut | JSONResponse:
    """A query: status (queued, processing, done, failed) and, when done, its answer.

    With ``wait_s`` the request waits (holding no thread) until the answer is ready or ``wait_s`` passed, so a
    client need not poll in a loop. With ``Accept: application/geo+json`` or ``?format=geojson`` the answer is
    a GeoJSON FeatureCollection: a Point per ranked pose, a Polygon view cone per pose, the identified
    buildings' footprints, ``attribution`` as a foreign member; a query not answered (yet) gets the same status
    code with an empty collection whose ``status`` (and ``error``) say why.
    """
    out = await long_poll(request, wait_s, partial(_query_model, settings, query_id, caller.tenant))
    if wants_geojson(request, format_name):
        body = await run_in_threadpool(partial(_load_query, settings, query_id, caller.tenant, geojson=True))
        return JSONResponse(body, media_type=GEOJSON_MEDIA_TYPE)
    return out


def _done_result(db: Database, query_id: int, tenant: str | None) -> tuple[QueryRow, dict[str, Any]]:
    """The query's row (of ``tenant``, else 404) and its stored answer; 409 while it has none."""
    row, _ = _load(db, query_id, tenant)
    if row["status"] != "done" or not row["result"]:
        raise ApiError(409, "not_ready", f"query {query_id} has no answer yet (status {row['status']})")
    return row, dict(row["result"])


@router.get(
    "/v1/queries/{query_id}/heatmap.png",
    responses={200: {"content": {"image/png": {}}}, **error_responses(404, 409)},
    response_class=Response,
    dependencies=[Depends(require_read)],
)
def get_heatmap_png(
    query_id: QueryId,
    db: Database = Depends(get_db),
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
    caller: Caller = Depends(request_caller),
) -> Response:
    """The answer as a picture that stands alone (PNG, 800 px wide, north up; :mod:`service.heatmap_png`).

    The probability map's cells over the map's streets and footprints, the top poses as view cones, a colour
    bar, a scale bar, a north arrow and the map data's attribution.
    """
    row, stored = _done_result(db, query_id, caller.tenant)
    result = QueryResult.model_validate(stored)
    map_row = require_map(db, row["map_id"], caller.tenant)
    png = heatmap_png(loaded_map(settings, store, map_row), result, map_attribution(map_row["attribution"]))
    return Response(png, media_type="image/png")


@router.get(
    "/v1/queries/{query_id}/answer.geojson",
    responses={200: {"content": {"application/geo+json": {}}}, **error_responses(404, 409)},
    response_class=Response,
    dependencies=[Depends(require_read)],
)
def get_answer_geojson(
    query_id: QueryId, db: Database = Depends(get_db), caller: Caller = Depends(request_caller)
) -> JSONResponse:
    """The ranked locations as GeoJSON points (properties: rank, heading, probabilities), with ``attribution``.

    ``GET /v1/queries/{id}?format=geojson`` adds view cones and the identified buildings.
    """
    row, result = _done_result(db, query_id, caller.tenant)
    body = {
        "type": "FeatureCollection",
        "features": pose_points(result["locations"]),
        "attribution": _attribution(db, row["map_id"]),
        "properties": {"query_id": query_id},
    }
    return JSONResponse(body, media_type=GEOJSON_MEDIA_TYPE)


@router.delete(
    "/v1/queries/{query_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=error_responses(404, 409),
    dependencies=[Depends(require_write)],
)
def delete_query(
    query_id: QueryId,
    db: Database = Depends(get_db),
    store: FileStore = Depends(get_store),
    caller: Caller = Depends(request_caller),
) -> Response:
    """Delete a query and its stored photo; a track's frame is deleted with its track (409 here)."""

    def delete(db: Database) -> list[str | None] | None:
        row = require_query(db, query_id, caller.tenant)
        if row.get("track_id") is not None:
            raise ApiError(
                409,
                "conflict",
                f"query {query_id} is frame {row['frame_index']} of track {row['track_id']}: delete the track",
                {"track_id": row["track_id"]},
            )
        deleted = query_store.delete_query(db, query_id)
        return None if deleted is None else [deleted["image_path"]]

    return delete_with_photos(db, store, f"query {query_id}", delete)


@router.get(
    "/v1/queries/{query_id}/image",
    responses={200: {"content": {t: {} for t in STORED_MEDIA_TYPES.values()}}, **READ_ERRORS},
    response_class=FileResponse,
    dependencies=[Depends(require_read)],
)
def get_query_image(
    query_id: QueryId,
    db: Database = Depends(get_db),
    store: FileStore = Depends(get_store),
    caller: Caller = Depends(request_caller),
) -> FileResponse:
    """The query photo as uploaded (its stored bytes, with the media type of its format)."""
    row, _ = _load(db, query_id, caller.tenant)
    if not row["image_path"]:
        raise ApiError(404, "not_found", f"query {query_id} has no stored photo")
    return stored_photo_response(store.local_path(row["image_path"]))
