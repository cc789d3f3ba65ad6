"""References: geo-tagged photos of a map, labelled by the ``label_reference`` job."""

from __future__ import annotations

import logging
from typing import Annotated, Any

from fastapi import APIRouter, Depends, File, Form, Query, Response, UploadFile, status
from fastapi.responses import FileResponse, JSONResponse

from db import Database, transaction
from db import jobs as job_store
from db import references as reference_store
from db.files import FileStore
from contracts.answers import EstimatedPose
from service.auth import require_read, require_write
from service.bounds import MapId, ReferenceId, check_bounds, documented
from service.deps import get_db, get_publisher, get_settings, get_store
from service.errors import ApiError
from service.images import STORED_MEDIA_TYPES, distance_outside_bbox_m, stored_photo_response, validate_image
from service.limits import require_queue_capacity
from service.models import (
    Position,
    ReferenceAccepted,
    ReferenceList,
    ReferenceOut,
    error_responses,
    timestamp,
)
from service.routes_maps import require_map
from service.settings import Settings
from service.spec import QUEUE_FULL_RESPONSE
from service.uploads import received_upload
from workers.broker import JobPublisher

log = logging.getLogger("geoloc.api")
router = APIRouter(tags=["references"])
READ_ERRORS = error_responses(404)
"""Errors a read answers itself (the specification adds auth, rate-limit and validation statuses)."""


def resolve_position(
    lat: float | None, lon: float | None, exif_lat: float | None, exif_lon: float | None
) -> tuple[float, float, str]:
    """The reference's position: the request's lat/lon if given, else EXIF GPS, else 422."""
    if (lat is None) != (lon is None):
        raise ApiError(422, "invalid_request", "give both lat and lon, or neither (to use the photo's EXIF GPS)")
    if lat is not None and lon is not None:
        check_bounds("lat", lat)
        check_bounds("lon", lon)
        return lat, lon, "request"
    if exif_lat is None or exif_lon is None:
        raise ApiError(
            422,
            "no_position",
            "no position: the photo has no GPS position in its EXIF and no lat/lon fields were given",
        )
    return exif_lat, exif_lon, "exif"


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
def upload_reference(
    map_id: MapId,
    image: Annotated[UploadFile, File(description="The photo (JPEG, PNG, WEBP or TIFF; checked by content)")],
    lat: Annotated[
        float | None, Form(description="Latitude (WGS84); overrides EXIF GPS", json_schema_extra=documented("lat"))
    ] = None,
    lon: Annotated[
        float | None, Form(description="Longitude (WGS84); overrides EXIF GPS", json_schema_extra=documented("lon"))
    ] = None,
    heading_deg: Annotated[
        float | None,
        Form(description="Prior heading, degrees clockwise from north", json_schema_extra=documented("heading_deg")),
    ] = None,
    focal_length_35mm: Annotated[
        float | None,
        Form(
            description="35 mm-equivalent focal length; overrides EXIF",
            json_schema_extra=documented("focal_length_35mm"),
        ),
    ] = None,
    db: Database = Depends(get_db),
    settings: Settings = Depends(get_settings),
    store: FileStore = Depends(get_store),
    publisher: JobPublisher = Depends(get_publisher),
) -> ReferenceAccepted | JSONResponse:
    """Add a geo-tagged reference photo and queue its labelling.

    202 with the reference and its job; 200 with the existing reference when the same photo
    (sha256) is already a reference of this map (``duplicate: true``, nothing queued).
    Errors: 404 unknown map, 413 too large (bytes or pixels), 415 not an image, 422 corrupt or
    truncated image, no position, or a position outside the map (with the distance), 429 while the
    job queue is full (retry after ``Retry-After`` seconds).
    """
    map_row = require_map(db, map_id)
    check_bounds("heading_deg", heading_deg)
    check_bounds("focal_length_35mm", focal_length_35mm)
    with received_upload(image, store, settings.max_image_bytes, "the image") as received:
        info = validate_image(received.path, max_pixels=settings.max_image_pixels, min_side=settings.min_image_side)
        ref_lat, ref_lon, source = resolve_position(lat, lon, info.gps_lat, info.gps_lon)
        distance = distance_outside_bbox_m(ref_lat, ref_lon, map_row["bbox_wgs84"])
        if distance > settings.position_margin_m:
            raise ApiError(
                422,
                "outside_map",
                f"the photo's position ({ref_lat:.6f}, {ref_lon:.6f}, from {source}) is {distance:.0f} m outside "
                f"map {map_id}'s bounding box (allowed margin {settings.position_margin_m:.0f} m)",
                {
                    "distance_m": round(distance, 1),
                    "margin_m": settings.position_margin_m,
                    "lat": ref_lat,
                    "lon": ref_lon,
                },
            )
        relative = f"images/{map_id}/{received.sha256}.{info.extension}"
        with transaction(db):  # duplicate check, rows and job are one unit
            db.lock(f"geoloc:reference:{map_id}:{received.sha256}")  # the same photo sent twice at once
            existing = reference_store.find_reference_by_sha256(db, map_id, received.sha256)
            if existing is None:
                received.move_to(relative)
                reference_id = reference_store.insert_reference(
                    db,
                    map_id=map_id,
                    image_path=relative,
                    original_filename=received.filename,
                    sha256=received.sha256,
                    size_bytes=received.size_bytes,
                    image_format=info.format,
                    width=info.width,
                    height=info.height,
                    gps_lat=ref_lat,
                    gps_lon=ref_lon,
                    position_source=source,
                    prior_heading_deg=heading_deg if heading_deg is not None else info.heading_deg,
                    focal_length_35mm=focal_length_35mm if focal_length_35mm is not None else info.focal_length_35mm,
                )
                job_id = job_store.enqueue_job(
                    db,
                    job_store.LABEL_REFERENCE,
                    {"reference_id": reference_id, "map_id": map_id},
                    max_attempts=settings.job_max_attempts,
                    map_id=map_id,
                    reference_id=reference_id,
                    max_queued=settings.max_queued_jobs,
                )
                reference_store.set_reference_job(db, reference_id, job_id)
    if existing is not None:
        out = ReferenceAccepted(
            id=existing["id"],
            map_id=map_id,
            job_id=existing["job_id"],
            status=existing["status"],
            sha256=existing["sha256"],
            duplicate=True,
        )
        return JSONResponse(out.model_dump(mode="json"), status_code=200)
    publisher.publish(db, [job_id])
    log.info("reference %d stored for map %d, job %d", reference_id, map_id, job_id)
    return ReferenceAccepted(id=reference_id, map_id=map_id, job_id=job_id, status="queued", sha256=received.sha256)


def reference_out(row: dict[str, Any], job: dict[str, Any] | None) -> ReferenceOut:
    """A reference row (and its job) as its API model."""
    status_now, error = reference_store.effective_status(row, job)
    estimated = None
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
        focal_length_35mm=row["focal_length_35mm"],
        estimated=estimated,
        buildings_seen=row["buildings_seen"],
        timings=row["timings"],
        created_at=timestamp(row["created_at"]),
        updated_at=timestamp(row["updated_at"]),
    )


@router.get(
    "/v1/references/{reference_id}",
    response_model=ReferenceOut,
    responses=error_responses(404),
    dependencies=[Depends(require_read)],
)
def get_reference(reference_id: ReferenceId, db: Database = Depends(get_db)) -> ReferenceOut:
    """A reference: its status (queued, processing, done, failed).

    When done, also the estimated pose, the buildings seen and timings.
    """
    row = reference_store.get_reference(db, reference_id)
    if row is None:
        raise ApiError(404, "not_found", f"reference {reference_id} not found")
    job = job_store.get_job(db, row["job_id"]) if row["job_id"] is not None else None
    return reference_out(row, job)


@router.delete(
    "/v1/references/{reference_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=error_responses(404),
    dependencies=[Depends(require_write)],
)
def delete_reference(
    reference_id: ReferenceId, db: Database = Depends(get_db), store: FileStore = Depends(get_store)
) -> Response:
    """Delete a reference with its labels, keypoints and index entries (its queued job is cancelled)."""
    with transaction(db):
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
    reference_id: ReferenceId, db: Database = Depends(get_db), store: FileStore = Depends(get_store)
) -> Response:
    """The photo with its building pixels coloured by identity; 409 until the reference is labelled.

    One colour per building, as in the paper's Fig. 5; uncertain columns are drawn paler.
    """
    from service.rendering import identity_overlay_png

    row = reference_store.get_reference(db, reference_id)
    if row is None:
        raise ApiError(404, "not_found", f"reference {reference_id} not found")
    arrays = reference_store.load_labels(db, reference_id)
    if arrays is None:
        raise ApiError(409, "not_ready", f"reference {reference_id} is not labelled yet (status {row['status']})")
    png = identity_overlay_png(store.local_path(row["image_path"]), arrays)
    return Response(png, media_type="image/png")


@router.get(
    "/v1/maps/{map_id}/references",
    response_model=ReferenceList,
    responses=READ_ERRORS,
    dependencies=[Depends(require_read)],
)
def list_map_references(
    map_id: MapId,
    after_id: Annotated[
        int, Query(ge=0, le=2**63 - 1, description="Return references with ids above this (paging cursor)")
    ] = 0,
    limit: Annotated[int, Query(ge=1, le=500, description="Most references in this page")] = 100,
    db: Database = Depends(get_db),
) -> ReferenceList:
    """A map's references, oldest first, a page at a time (follow ``next_after_id``).

    Each with its status and, once labelled, its estimated pose; ``counts`` and ``total`` cover the
    whole map (ingestion progress).
    """
    require_map(db, map_id)
    rows = reference_store.list_references_after(db, map_id, after_id=after_id, limit=limit + 1)
    page = rows[:limit]
    counts = reference_store.effective_status_counts(db, map_id)
    return ReferenceList(
        map_id=map_id,
        references=[
            reference_out(row, job_store.get_job(db, row["job_id"]) if row["job_id"] is not None else None)
            for row in page
        ],
        total=sum(counts.values()),
        counts=counts,
        next_after_id=page[-1]["id"] if len(rows) > limit else None,
    )


@router.get(
    "/v1/references/{reference_id}/image",
    responses={200: {"content": {t: {} for t in STORED_MEDIA_TYPES.values()}}, **READ_ERRORS},
    response_class=FileResponse,
    dependencies=[Depends(require_read)],
)
def get_reference_image(
    reference_id: ReferenceId, db: Database = Depends(get_db), store: FileStore = Depends(get_store)
) -> FileResponse:
    """The reference photo as uploaded (its stored bytes, with the media type of its format)."""
    row = reference_store.get_reference(db, reference_id)
    if row is None:
        raise ApiError(404, "not_found", f"reference {reference_id} not found")
    return stored_photo_response(store.local_path(row["image_path"]))
