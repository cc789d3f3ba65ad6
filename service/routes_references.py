"""References: geo-tagged photos of a map, labelled by the ``label_reference`` job.

An upload goes through the reference-upload use-case (:class:`service.intake_references.ReferenceIntake`).
"""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, Query, Request, Response, UploadFile, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse

from contracts.answers import BuildingInPhoto, EstimatedPose
from contracts.api import Position, ReferenceAccepted, ReferenceList, ReferenceOut
from contracts.jobs import PLACE_SEQUENCE
from contracts.licenses import map_attribution
from contracts.settings import Settings
from db import Database, transaction
from db import jobs as job_store
from db import references as reference_store
from db.files import FileStore
from db.rows import JobRow, ReferenceRow
from service.auth import Caller, request_caller, require_read, require_write
from service.bounds import MapId, ReferenceId, bounded_form
from service.deps import app_settings, get_db, get_publisher, get_store
from service.errors import ApiError
from service.geojson import GEOJSON_MEDIA_TYPE, GEOJSON_RESPONSE, GeoJsonFormat, references_collection, wants_geojson
from service.images import ACCEPTED_NAMES, STORED_MEDIA_TYPES, stored_photo_response
from service.intake_references import ReferenceForm, ReferenceIntake
from service.limits import require_queue_capacity
from service.reads import READ_ERRORS, work_status
from service.rendering import identity_overlay_png
from service.responses import error_responses, timestamp
from service.spec import QUEUE_FULL_RESPONSE
from service.tenancy import require_map, require_reference
from workers.broker import JobPublisher

log = logging.getLogger("geoloc.api")
router = APIRouter(tags=["references"])


SequenceField = Annotated[
    str | None,
    Form(
        max_length=200,
        description="The walk this photo belongs to (any id the client chooses; overrides the photo's "
        "Mapillary sequence id). A walk's references are placed jointly once labelled (docs/method.md); "
        "without one, one camera's captures within 60 s and 50 m of each other form a walk",
    ),
]
"""The reference upload's ``sequence`` form field."""


def reference_form(
    lat: Annotated[float | None, bounded_form("lat", "Latitude (WGS84); overrides EXIF GPS")] = None,
    lon: Annotated[float | None, bounded_form("lon", "Longitude (WGS84); overrides EXIF GPS")] = None,
    heading_deg: Annotated[
        float | None, bounded_form("heading_deg", "Prior heading, degrees clockwise from north")
    ] = None,
    focal_length_35mm: Annotated[
        float | None, bounded_form("focal_length_35mm", "35 mm-equivalent focal length; overrides EXIF")
    ] = None,
    sequence: SequenceField = None,
    place: Annotated[
        str | None,
        Form(
            max_length=200,
            description="A place of the map as the position when there is no lat/lon: a building's name, an "
            "address, a street (GET /v1/maps/{id}/places); overrides EXIF GPS",
        ),
    ] = None,
) -> ReferenceForm:
    """The reference upload's form fields (but the photo), as the upload route reads them (a dependency)."""
    stated_sequence = sequence.strip() if sequence and sequence.strip() else None
    return ReferenceForm(lat, lon, heading_deg, focal_length_35mm, stated_sequence, place)


@router.post(
    "/v1/maps/{map_id}/references",
    response_model=ReferenceAccepted,
    status_code=status.HTTP_202_ACCEPTED,
    responses={
        200: {"model": ReferenceAccepted, "description": "Already a reference of this map"},
        **error_responses(404, 413, 415, 422),
        **QUEUE_FULL_RESPONSE,
    },
    dependencies=[Depends(require_write), Depends(require_queue_capacity)],
)
async def upload_reference(
    map_id: MapId,
    image: Annotated[UploadFile, File(description=f"The photo ({ACCEPTED_NAMES}; checked by content)")],
    form: Annotated[ReferenceForm, Depends(reference_form)],
    settings: Settings = Depends(app_settings),
    store: FileStore = Depends(get_store),
    publisher: JobPublisher = Depends(get_publisher),
    caller: Caller = Depends(request_caller),
) -> ReferenceAccepted | JSONResponse:
    """Add a geo-tagged reference photo and queue its labelling.

    202 with the reference and its job; 200 with the existing reference when the same photo
    (sha256) is already a reference of this map (``duplicate: true``, nothing queued).
    Errors: 404 unknown map, 413 too large (bytes or pixels), 415 not an image, 422 corrupt or
    truncated image, a panorama (``unsupported_projection``: equirectangular by its XMP or its 2:1 shape;
    only perspective photos are supported), no position, or a position outside the map (with the
    distance), a ``place`` that is ambiguous (``ambiguous_place``, with candidates) or unknown
    (``unknown_place``), 429 while the job queue is full (retry after ``Retry-After`` seconds).
    """
    intake = ReferenceIntake(settings, store, publisher, form)
    accepted = await run_in_threadpool(intake.accept, map_id, image, caller.tenant)
    if intake.duplicate is not None:
        existing = intake.duplicate
        out = ReferenceAccepted(
            id=existing["id"],
            map_id=map_id,
            job_id=existing["job_id"],
            status=existing["status"],
            sha256=existing["sha256"],
            duplicate=True,
        )
        return JSONResponse(out.model_dump(mode="json"), status_code=200)
    log.info("reference %d stored for map %d, job %d", accepted.subject_id, map_id, accepted.job_id)
    return ReferenceAccepted(
        id=accepted.subject_id, map_id=map_id, job_id=accepted.job_id, status="queued", sha256=accepted.sha256
    )


def reference_out(row: ReferenceRow, job: JobRow | None, attribution: str) -> ReferenceOut:
    """A reference row (and its job) as its API model, with its map's ``attribution``."""
    status_now, error = work_status(row["status"], row["error"], job)
    estimated, buildings = None, row["buildings_seen"]
    if row["estimated_lat"] is not None or row["estimated_heading_deg"] is not None:
        estimated = EstimatedPose(
            lat=row["estimated_lat"], lon=row["estimated_lon"], heading_deg=row["estimated_heading_deg"]
        )
    return ReferenceOut(
        id=row["id"],
        map_id=row["map_id"],
        status=status_now,
        error=error,
        job_id=row["job_id"],
        sha256=row["sha256"],
        original_filename=row["original_filename"],
        width=row["width"],
        height=row["height"],
        position=Position(lat=row["gps_lat"], lon=row["gps_lon"], source=row["position_source"]),
        prior_heading_deg=row["prior_heading_deg"],
        prior_heading_accuracy_deg=row["prior_heading_accuracy_deg"],
        focal_length_35mm=row["focal_length_35mm"],
        sequence_id=row["sequence_id"],
        capture_time=row["capture_time"],
        placement=row["placement"],
        estimated=estimated,
        buildings_seen=None if buildings is None else [BuildingInPhoto.model_validate(b) for b in buildings],
        timings=row["timings"],
        attribution=attribution,
        created_at=timestamp(row["created_at"]),
        updated_at=timestamp(row["updated_at"]),
    )


@router.get(
    "/v1/references/{reference_id}",
    response_model=ReferenceOut,
    responses=error_responses(404),
    dependencies=[Depends(require_read)],
)
def get_reference(
    reference_id: ReferenceId, db: Database = Depends(get_db), caller: Caller = Depends(request_caller)
) -> ReferenceOut:
    """A reference: its status (queued, processing, done, failed).

    When done, also the estimated pose, the buildings seen and timings.
    """
    row = require_reference(db, reference_id, caller.tenant)
    job = job_store.get_job(db, row["job_id"]) if row["job_id"] is not None else None
    return reference_out(row, job, map_attribution(require_map(db, row["map_id"], caller.tenant)["attribution"]))


@router.delete(
    "/v1/references/{reference_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=error_responses(404),
    dependencies=[Depends(require_write)],
)
def delete_reference(
    reference_id: ReferenceId,
    db: Database = Depends(get_db),
    store: FileStore = Depends(get_store),
    caller: Caller = Depends(request_caller),
) -> Response:
    """Delete a reference with its labels, keypoints and index entries (its queued job is cancelled)."""
    with transaction(db):
        require_reference(db, reference_id, caller.tenant)
        deleted = reference_store.delete_reference(db, reference_id)
    if deleted is None:
        raise ApiError(404, "not_found", f"reference {reference_id} not found")
    store.delete(deleted["image_path"])
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/v1/references/{reference_id}/labels.png",
    responses={200: {"content": {"image/png": {}}}, **error_responses(404, 409)},
    response_class=Response,
    dependencies=[Depends(require_read)],
)
def get_labels_png(
    reference_id: ReferenceId,
    db: Database = Depends(get_db),
    store: FileStore = Depends(get_store),
    caller: Caller = Depends(request_caller),
) -> Response:
    """The photo with its building pixels coloured by identity; 409 until the reference is labelled.

    One colour per building, as in the paper's Fig. 5; uncertain columns are drawn paler.
    """
    row = require_reference(db, reference_id, caller.tenant)
    labels = reference_store.load_labels(db, reference_id)
    if labels is None:
        raise ApiError(409, "not_ready", f"reference {reference_id} is not labelled yet (status {row['status']})")
    png = identity_overlay_png(store.local_path(row["image_path"]), labels)
    return Response(png, media_type="image/png")


@router.get(
    "/v1/maps/{map_id}/references",
    response_model=ReferenceList,
    responses={200: {"content": GEOJSON_RESPONSE}, **READ_ERRORS},
    dependencies=[Depends(require_read)],
)
def list_map_references(
    request: Request,
    map_id: MapId,
    after_id: Annotated[
        int, Query(ge=0, le=2**63 - 1, description="Return references with ids above this (paging cursor)")
    ] = 0,
    limit: Annotated[int, Query(ge=1, le=500, description="Most references in this page")] = 100,
    format_name: GeoJsonFormat = None,
    db: Database = Depends(get_db),
    caller: Caller = Depends(request_caller),
) -> ReferenceList | JSONResponse:
    """A map's references, oldest first, a page at a time (follow ``next_after_id``).

    Each with its status and, once labelled, its estimated pose; ``counts`` and ``total`` cover the
    whole map (ingestion progress). With ``Accept: application/geo+json`` or ``?format=geojson``: the page as
    a GeoJSON FeatureCollection, a Point per reference at its estimated pose (else its uploaded position).
    """
    attribution = map_attribution(require_map(db, map_id, caller.tenant)["attribution"])
    # The progress first, the rows after: a placement commits its poses before its job ends, so a page that
    # says nothing is pending holds the final poses (read the other way round, a walk placed between the two
    # reads showed its old poses beside ``walks_placing`` 0, and a client stopped polling on them).
    counts = reference_store.effective_status_counts(db, map_id)
    walks_placing = job_store.pending_job_count(db, PLACE_SEQUENCE, map_id)
    rows = reference_store.list_references_after(db, map_id, after_id=after_id, limit=limit + 1)
    page = rows[:limit]
    listed = ReferenceList(
        map_id=map_id,
        references=[
            reference_out(row, job_store.get_job(db, row["job_id"]) if row["job_id"] is not None else None, attribution)
            for row in page
        ],
        total=sum(counts.values()),
        counts=counts,
        walks_placing=walks_placing,
        next_after_id=page[-1]["id"] if len(rows) > limit else None,
        attribution=attribution,
    )
    if wants_geojson(request, format_name):
        return JSONResponse(references_collection(listed), media_type=GEOJSON_MEDIA_TYPE)
    return listed


@router.get(
    "/v1/references/{reference_id}/image",
    responses={200: {"content": {t: {} for t in STORED_MEDIA_TYPES.values()}}, **READ_ERRORS},
    response_class=FileResponse,
    dependencies=[Depends(require_read)],
)
def get_reference_image(
    reference_id: ReferenceId,
    db: Database = Depends(get_db),
    store: FileStore = Depends(get_store),
    caller: Caller = Depends(request_caller),
) -> FileResponse:
    """The reference photo as uploaded (its stored bytes, with the media type of its format)."""
    row = require_reference(db, reference_id, caller.tenant)
    return stored_photo_response(store.local_path(row["image_path"]))
