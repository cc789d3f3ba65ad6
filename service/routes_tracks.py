"""Tracks: a walk of photos located together. Answered by the ``locate_track`` job in the worker pool (issue 20).

``POST /v1/maps/{id}/tracks`` takes the photos in one multipart request (the field ``images`` repeated, in frame
order) or a JSON body naming earlier queries of the map (:class:`contracts.api.TrackFromQueries`), stores
them as the track's frames (query rows: :mod:`db.tracks`) with one job, and waits up to ``wait_s`` for the answer
as a query does (200 with the answer, 202 to poll ``GET /v1/tracks/{id}``, 429 while the queue is full).
``GET /v1/tracks/{id}`` serves the frames in order, each with its pose, and as GeoJSON the trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, Query, Request, Response, UploadFile, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from pydantic import TypeAdapter, ValidationError

from contracts.answers import TrackFrameResult, TrackResult
from contracts.api import FramePrior, TrackFromQueries, TrackOut
from contracts.licenses import map_attribution
from contracts.queries import QueryPreset
from contracts.settings import Settings
from db import Database
from db import jobs as job_store
from db import maps as map_store
from db import tracks as track_store
from db.files import FileStore
from service.auth import Caller, request_caller, require_read, require_write
from service.bounds import MapId, TrackId, bounded_form, check_bounds
from service.deps import app_settings, get_db, get_publisher, get_store, open_db
from service.errors import ApiError
from service.geojson import GEOJSON_MEDIA_TYPE, GEOJSON_RESPONSE, GeoJsonFormat, track_collection, wants_geojson
from service.images import ACCEPTED_NAMES
from service.intake_tracks import TrackForm, TrackIntake
from service.limits import require_queue_capacity
from service.photo_deletion import delete_with_photos
from service.reads import work_status
from service.responses import error_responses, timestamp
from service.spec import QUEUE_FULL_RESPONSE
from service.tenancy import require_track
from service.waiting import answered, long_poll
from workers.broker import JobPublisher

router = APIRouter(tags=["tracks"])
_PRIORS = TypeAdapter(list[FramePrior | None])


def load_track(settings: Settings, track_id: int, tenant: str | None) -> TrackOut:
    """The track as its API model: the stored answer's frames when done, else each frame's query and file name."""
    db = open_db(settings)
    try:
        row = require_track(db, track_id, tenant)
        job = job_store.get_job(db, row["job_id"]) if row["job_id"] else None
        state, error = work_status(row["status"], row["error"], job)
        result = TrackResult.model_validate(row["result"]) if row["result"] else None
        if result is not None:
            frames = result.frames
        else:
            frames = [
                TrackFrameResult(
                    index=i,
                    query_id=q["id"],
                    original_filename=q["params"].original_filename,
                    capture_time=(row["params"].get("capture_times") or [None] * (i + 1))[i],
                )
                for i, q in enumerate(track_store.track_frames(db, track_id))
            ]
        map_row = map_store.get_map(db, row["map_id"])
        return TrackOut(
            id=row["id"],
            map_id=row["map_id"],
            status=state,
            error=error,
            job_id=row["job_id"],
            params=row["params"],
            frames=frames,
            search=None if result is None else result.search,
            timings_ms=None if result is None else result.timings_ms,
            attribution=map_attribution(None if map_row is None else map_row["attribution"]),
            created_at=timestamp(row["created_at"]),
            updated_at=timestamp(row["updated_at"]),
        )
    finally:
        db.close()


def _reasons(exc: ValidationError) -> str:
    return "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors(include_url=False))


def _priors(text: str | None) -> list[FramePrior | None]:
    """The ``priors`` form field: a JSON list, one entry (or null) per frame; 422 with the reason otherwise."""
    if text is None or not text.strip():
        return []
    try:
        return _PRIORS.validate_json(text)
    except ValidationError as exc:
        raise ApiError(
            422, "invalid_request", f"priors must be a JSON list of per-frame priors or nulls: {_reasons(exc)}"
        ) from None


async def _json_body(request: Request) -> TrackFromQueries:
    """The JSON body of a track of earlier queries; 422 with the reason when it is not one."""
    try:
        return TrackFromQueries.model_validate_json(await request.body())
    except ValidationError as exc:
        raise ApiError(422, "invalid_request", f"the JSON body is not a track of queries: {_reasons(exc)}") from None


_JSON_BODY = {
    "requestBody": {
        "content": {
            "application/json": {
                "schema": TrackFromQueries.model_json_schema(),
                "example": {"query_ids": [41, 42, 43], "wait_s": 60},
            }
        }
    }
}


@dataclass(frozen=True)
class TrackFields:
    """The multipart track upload's form fields (but the photos), as sent: ``priors`` is the JSON text."""

    priors: str | None
    use_exif_gps: bool
    by_capture_time: bool
    top_n: int
    k: int
    wait_s: float
    preset: QueryPreset | None


def track_fields(
    priors: Annotated[
        str | None,
        Form(
            description='Per-frame priors: a JSON list with one entry per frame, each null or {"lat", "lon", '
            '"radius_m", "heading_deg", "place"} as a query\'s fields',
            max_length=200_000,
        ),
    ] = None,
    use_exif_gps: Annotated[bool, Form(description="Use each photo's EXIF GPS as its prior position")] = True,
    by_capture_time: Annotated[bool, Form(description="Order the frames by their EXIF capture time")] = False,
    top_n: Annotated[int, bounded_form("top_n", "How many distinct locations each frame's answer holds")] = 10,
    k: Annotated[int, bounded_form("k", "How many references to retrieve for identities")] = 4,
    wait_s: Annotated[float, bounded_form("wait_s", "How long to wait for the answer before 202")] = 60.0,
    preset: Annotated[QueryPreset | None, Form(description="fast, balanced or accurate")] = None,
) -> TrackFields:
    """The multipart track upload's form fields, as the upload route reads them (a dependency)."""
    return TrackFields(priors, use_exif_gps, by_capture_time, top_n, k, wait_s, preset)


@router.post(
    "/v1/maps/{map_id}/tracks",
    response_model=TrackOut,
    responses={
        202: {"model": TrackOut, "description": "Not answered within wait_s: poll the track"},
        **error_responses(404, 413, 422),
        **QUEUE_FULL_RESPONSE,
    },
    dependencies=[Depends(require_read), Depends(require_queue_capacity)],
    openapi_extra=_JSON_BODY,
)
async def create_track(
    request: Request,
    map_id: MapId,
    images: Annotated[
        list[UploadFile] | None,
        File(description=f"The frames' photos, the field repeated in frame order ({ACCEPTED_NAMES})"),
    ] = None,
    fields: TrackFields = Depends(track_fields),
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
    publisher: JobPublisher = Depends(get_publisher),
    caller: Caller = Depends(request_caller),
) -> TrackOut | JSONResponse:
    """Locate a walk of photos together: each frame's pose (position, heading, 90 % radius, source, buildings).

    Multipart: ``images`` repeated in frame order (``by_capture_time`` orders them by EXIF time), optional
    ``priors`` per frame, each frame's EXIF GPS and compass as a query's. JSON (``Content-Type:
    application/json``): ``{"query_ids": [...]}`` names earlier queries of this map (422 ``foreign_query`` for
    another map's). At most ``GEOLOC_MAX_TRACK_FRAMES`` frames (413 ``too_many_frames``); a frame that is not a
    photo is a 422 naming it (``details.frame``). 200 with the answer, 202 after ``wait_s``; 429 while the job
    queue is full.
    """
    intake = TrackIntake(settings, store, publisher)
    if "application/json" in request.headers.get("content-type", ""):
        body = await _json_body(request)
        wait_s = body.wait_s
        track_id, job_id = await run_in_threadpool(intake.accept_queries, map_id, body, caller.tenant)
    else:
        wait_s = fields.wait_s
        for name, value in (("top_n", fields.top_n), ("k", fields.k), ("wait_s", wait_s)):
            check_bounds(name, value)
        form = TrackForm(
            fields.use_exif_gps, fields.by_capture_time, fields.top_n, fields.k, wait_s, fields.preset,
            _priors(fields.priors),
        )  # fmt: skip
        track_id, job_id = await run_in_threadpool(intake.accept_uploads, map_id, form, images or [], caller.tenant)
    return await answered(request, job_id, wait_s, partial(load_track, settings, track_id, caller.tenant))


@router.get(
    "/v1/tracks/{track_id}",
    response_model=TrackOut,
    responses={200: {"content": GEOJSON_RESPONSE}, **error_responses(404)},
    dependencies=[Depends(require_read)],
)
async def get_track(
    request: Request,
    track_id: TrackId,
    wait_s: Annotated[
        float, Query(ge=0, le=300, description="Wait up to this long for the answer (a long poll)")
    ] = 0.0,
    format_name: GeoJsonFormat = None,
    settings: Settings = Depends(app_settings),
    caller: Caller = Depends(request_caller),
) -> TrackOut | JSONResponse:
    """A track: status and its frames in order, each with its pose once located.

    A frame: ``lat``, ``lon``, ``heading_deg``, ``uncertainty_radius_m``, ``source``, ``outlier``, ``buildings``.
    With ``Accept: application/geo+json`` or ``?format=geojson``: a FeatureCollection of the trajectory (a
    LineString through the frames in order), a Point and a view cone per frame.
    Each frame's whole answer is its query's (``GET /v1/queries/{query_id}``).
    """
    out = await long_poll(request, wait_s, partial(load_track, settings, track_id, caller.tenant))
    if wants_geojson(request, format_name):
        return JSONResponse(await run_in_threadpool(partial(track_collection, out)), media_type=GEOJSON_MEDIA_TYPE)
    return out


@router.delete(
    "/v1/tracks/{track_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=error_responses(404),
    dependencies=[Depends(require_write)],
)
def delete_track(
    track_id: TrackId,
    db: Database = Depends(get_db),
    store: FileStore = Depends(get_store),
    caller: Caller = Depends(request_caller),
) -> Response:
    """Delete a track with its frames (their queries and photos; a photo another query still uses stays)."""

    def delete(db: Database) -> list[str | None] | None:
        require_track(db, track_id, caller.tenant)
        return track_store.delete_track(db, track_id=track_id)

    return delete_with_photos(db, store, f"track {track_id}", delete)
