"""The track job: a track's frames (query photos, in order) located together by the track stage (issue 20).

Each frame's photo is loaded and analysed as a query's is (:func:`workers.handler_helpers.stored_photo`,
:func:`geoloc.vision.evidence.analyze_photo`), with its own stored priors
(:func:`workers.handler_helpers.query_priors`); :func:`geoloc.localize.track.locate_track` answers them together.
Each frame's query row gets its whole answer (:func:`workers.handler_helpers.query_result`, so
``GET /v1/queries/{id}`` serves it as any query's) and the track its :class:`contracts.answers.TrackResult`: per
frame the rank-1 pose (its position, heading, 90 % radius, source), the ``outlier`` flag and the buildings; all
in one transaction, so a job that runs again after a crash leaves the same state.
"""

from __future__ import annotations

import time
from datetime import UTC, datetime

from contracts.answers import QueryResult, TrackFrameResult, TrackResult
from contracts.jobs import LOCATE_TRACK, LocateTrackPayload, LocateTrackResult
from contracts.queries import DEFAULT_QUERY_PRESET
from db import Database, transaction
from db import queries as query_store
from db import tracks as track_store
from db.rows import QueryRow
from geoloc.localize.query import preset_config
from geoloc.localize.track import TrackFrame, locate_track
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import analyze_photo
from workers.context import worker_context
from workers.handler_helpers import (
    city_map_for,
    query_priors,
    query_result,
    reference_store_for,
    stored_photo,
    vocabulary_for,
)
from workers.handlers import PermanentJobError, answer_checked, register


def capture_seconds(value: str | None) -> float | None:
    """A stored capture time (ISO 8601) as Unix seconds; a naive (camera) time is read as UTC; None if unreadable."""
    if value is None:
        return None
    try:
        moment = datetime.fromisoformat(value)
    except ValueError:
        return None
    return (moment if moment.tzinfo else moment.replace(tzinfo=UTC)).timestamp()


def frame_result(
    index: int, row: QueryRow, capture_time: str | None, result: QueryResult, outlier: bool
) -> TrackFrameResult:
    """Frame ``index``'s summary in the track: its answer's rank-1 location, the outlier flag, the buildings."""
    best = result.locations[0] if result.locations else None
    return TrackFrameResult(
        index=index,
        query_id=row["id"],
        original_filename=row["params"].original_filename,
        capture_time=capture_time,
        lat=None if best is None else best.lat,
        lon=None if best is None else best.lon,
        heading_deg=None if best is None else best.heading_deg,
        uncertainty_radius_m=None if best is None else best.uncertainty_radius_m,
        source=None if best is None else best.source,
        outlier=outlier,
        hfov_deg=result.camera.hfov_deg,
        buildings=result.buildings,
    )


@register(LOCATE_TRACK, LocateTrackPayload)
def locate_track_job(db: Database, payload: LocateTrackPayload) -> LocateTrackResult:
    """Locate a track's frames together; store each frame's answer on its query and the track's on the track."""
    context = worker_context()
    track_id, map_id = payload.track_id, payload.map_id
    track = track_store.get_track(db, track_id)
    if track is None:
        raise PermanentJobError(f"track {track_id} no longer exists")
    rows = track_store.track_frames(db, track_id)
    if not rows:
        raise PermanentJobError(f"track {track_id} has no frames")
    params = track["params"]
    capture_times: list[str | None] = list(params.get("capture_times") or [None] * len(rows))
    city = city_map_for(db, map_id)
    t0 = time.perf_counter()
    photos: list[Photo] = []
    frames: list[TrackFrame] = []
    for row, capture_time in zip(rows, capture_times, strict=True):
        if row["image_path"] is None:
            raise PermanentJobError(f"frame {row['frame_index']} of track {track_id} has no stored photo")
        photo = stored_photo(row["image_path"], row["params"].focal_length_35mm)
        position_prior, heading_prior = query_priors(db, map_id, city, row["params"])
        evidence = analyze_photo(photo, context=context)
        photos.append(photo)
        frames.append(TrackFrame(photo, evidence, position_prior, heading_prior, capture_seconds(capture_time)))
    preset = params.get("preset") or DEFAULT_QUERY_PRESET
    answer = locate_track(
        city,
        frames,
        reference_store_for(db, map_id),
        vocabulary_for(db, map_id),
        preset_config(preset, k=int(params.get("k", 4))),
        top_n=int(params.get("top_n", 10)),
        context=context,
    )
    total_ms = round(1e3 * (time.perf_counter() - t0), 1)
    with answer_checked("track answer"):
        results = [
            query_result(city, photo, frame.answer, {k: round(v, 1) for k, v in frame.answer.timings_ms.items()})
            for photo, frame in zip(photos, answer.frames, strict=True)
        ]
        summary = TrackResult(
            frames=[
                frame_result(i, row, capture_times[i], result, frame.outlier)
                for i, (row, result, frame) in enumerate(zip(rows, results, answer.frames, strict=True))
            ],
            search=answer.search.model_copy(update={"preset": preset}),
            timings_ms={**{k: round(v, 1) for k, v in answer.timings_ms.items()}, "total": total_ms},
        )
    with transaction(db):
        if not track_store.update_track_result(db, track_id, status="done", result=summary.model_dump(mode="json")):
            raise PermanentJobError(f"track {track_id} was deleted while it was located")
        for row, result in zip(rows, results, strict=True):
            query_store.update_query_result(db, row["id"], status="done", result=result.model_dump(mode="json"))
    located = sum(frame.lat is not None for frame in summary.frames)
    outliers = sum(frame.outlier for frame in summary.frames)
    return LocateTrackResult(track_id=track_id, frames=len(rows), located=located, outliers=outliers)
