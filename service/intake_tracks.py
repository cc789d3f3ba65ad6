"""The track-upload use-case: several photos (or earlier queries) stored as one track's frames with one job.

A track's frames are query rows (:mod:`db.tracks`), so each uploaded frame goes through what a query upload
checks (:class:`service.intake_queries.QueryIntake`: its form's bounds, its photo by content, its prior position
inside the map) with its own priors; an error names the frame (``details.frame``, from 0 in the order sent).
A frame that is not a photo is a 422 (not the 415 of a lone query: the request as a whole is well formed, one of
its parts is not). All frames, their rows, the track and its one ``locate_track`` job are stored in one
transaction; nothing is stored when any frame is refused.

Decision (order): frames keep the order they were sent in; ``by_capture_time`` sorts them by the photos' EXIF
capture times (a naive camera time read as UTC; frames without one keep their place after those with one;
ties keep the sent order).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any

from fastapi import UploadFile

from contracts.api import FramePrior, TrackFromQueries
from contracts.jobs import LOCATE_TRACK, LocateTrackPayload
from contracts.queries import QueryParams, QueryPreset
from contracts.settings import Settings
from db import Database, transaction
from db import jobs as job_store
from db import queries as query_store
from db import tracks as track_store
from db.files import FileStore
from db.rows import MapRow, QueryRow
from service.deps import open_db
from service.errors import ApiError
from service.images import validate_image
from service.intake_queries import QueryForm, QueryIntake
from service.tenancy import require_query, require_ready_map
from service.uploads import ReceivedFile, received_upload
from workers.broker import JobPublisher


@dataclass(frozen=True)
class TrackForm:
    """What applies to every frame of a multipart track (a frame's priors are in ``priors``)."""

    use_exif_gps: bool
    by_capture_time: bool
    top_n: int
    k: int
    wait_s: float
    preset: QueryPreset | None
    priors: list[FramePrior | None]


@dataclass(frozen=True)
class Frame:
    """One frame ready to store: its row's parameters, photo key and checksum, capture time, received file."""

    params: QueryParams
    key: str
    sha256: str
    capture_time: str | None
    received: ReceivedFile | None = None


def _capture_key(capture_time: str | None) -> float:
    if capture_time is None:
        return float("inf")
    with contextlib.suppress(ValueError):
        moment = datetime.fromisoformat(capture_time)
        return (moment if moment.tzinfo else moment.replace(tzinfo=UTC)).timestamp()
    return float("inf")


def framed(index: int, exc: ApiError) -> ApiError:
    """``exc`` about frame ``index``: the frame named in its message and ``details.frame``; a 415 becomes a 422."""
    details = {**(exc.details or {}), "frame": index}
    return ApiError(422 if exc.status == 415 else exc.status, exc.code, f"frame {index}: {exc.message}", details)


def check_frame_count(settings: Settings, count: int) -> None:
    """413 ``too_many_frames`` above ``GEOLOC_MAX_TRACK_FRAMES``; 422 for an empty track."""
    if count == 0:
        raise ApiError(422, "invalid_request", "a track needs at least one frame (the field images, repeated)")
    if count > settings.max_track_frames:
        raise ApiError(
            413,
            "too_many_frames",
            f"a track holds at most {settings.max_track_frames} frames, got {count}",
            {"limit_frames": settings.max_track_frames, "frames": count},
        )


class TrackIntake:
    """Store a track of map ``map_id`` and queue its job (blocking: run in a worker thread)."""

    def __init__(self, settings: Settings, store: FileStore, publisher: JobPublisher) -> None:
        self.settings = settings
        self.store = store
        self.publisher = publisher

    def _frame(self, map_row: MapRow, form: TrackForm, index: int, upload: UploadFile, stack: Any) -> Frame:
        prior = form.priors[index] or FramePrior()
        query_form = QueryForm(
            prior.lat, prior.lon, prior.radius_m, prior.heading_deg, form.use_exif_gps, prior.place, None,
            form.top_n, form.k, form.wait_s, form.preset,
        )  # fmt: skip
        intake = QueryIntake(self.settings, self.store, self.publisher, query_form)
        try:
            intake.check_form()
            received: ReceivedFile = stack.enter_context(
                received_upload(upload, self.store, self.settings.max_image_bytes, "the image")
            )
            info = validate_image(
                received.path, max_pixels=self.settings.max_image_pixels, min_side=self.settings.min_image_side
            )
            intake.check_photo(map_row, info)
        except ApiError as exc:
            raise framed(index, exc) from None
        key = f"{QueryIntake.folder}/{map_row['id']}/{received.sha256}.{info.extension}"
        return Frame(intake.params(received, info), key, received.sha256, info.capture_time, received)

    def accept_uploads(
        self, map_id: int, form: TrackForm, images: Sequence[UploadFile], tenant: str | None
    ) -> tuple[int, int]:
        """Check and store uploaded frames of a map of ``tenant``; returns (track id, job id)."""
        check_frame_count(self.settings, len(images))
        if len(form.priors) not in (0, len(images)):
            raise ApiError(
                422, "invalid_request", f"priors has {len(form.priors)} entries for {len(images)} frames: one per frame"
            )
        form = replace(form, priors=form.priors or [None] * len(images))
        db = open_db(self.settings)
        try:
            map_row = require_ready_map(db, map_id, tenant)
            with contextlib.ExitStack() as stack:
                frames = [self._frame(map_row, form, i, image, stack) for i, image in enumerate(images)]
                return self._store(db, map_id, frames, form.by_capture_time, form.top_n, form.k, form.preset)
        finally:
            db.close()

    def accept_queries(self, map_id: int, body: TrackFromQueries, tenant: str | None) -> tuple[int, int]:
        """A track of earlier queries' photos (copied as new frame rows; the queries stay as they are).

        Another tenant's query is "not found", as a missing one (no existence leak).
        """
        check_frame_count(self.settings, len(body.query_ids))
        db = open_db(self.settings)
        try:
            require_ready_map(db, map_id, tenant)
            frames = []
            for index, query_id in enumerate(body.query_ids):
                try:
                    row: QueryRow | None = require_query(db, query_id, tenant)
                except ApiError:
                    row = None
                if row is None or row["image_path"] is None:
                    # a named resource that does not exist (or another tenant's) is a 404, as in a path
                    raise ApiError(404, "not_found", f"frame {index}: query {query_id} not found", {"frame": index})
                if row["map_id"] != map_id:
                    raise ApiError(
                        422,
                        "foreign_query",
                        f"frame {index}: query {query_id} belongs to map {row['map_id']}, not map {map_id}",
                        {"frame": index, "query_id": query_id},
                    )
                try:
                    info = validate_image(self.store.local_path(row["image_path"]), max_pixels=2**62, min_side=0)
                except ApiError as exc:
                    raise framed(index, exc) from None
                params = row["params"].model_copy(update={"top_n": body.top_n, "k": body.k, "preset": body.preset})
                frames.append(Frame(params, row["image_path"], row["sha256"] or "", info.capture_time))
            return self._store(db, map_id, frames, body.by_capture_time, body.top_n, body.k, body.preset)
        finally:
            db.close()

    def _store(
        self,
        db: Database,
        map_id: int,
        frames: list[Frame],
        by_time: bool,
        top_n: int,
        k: int,
        preset: QueryPreset | None,
    ) -> tuple[int, int]:
        """The track, its frames (photos placed) and its job in one transaction; the job published after."""
        if by_time:
            frames = sorted(frames, key=lambda f: _capture_key(f.capture_time))  # stable: ties keep the sent order
        params = {
            "order": "capture_time" if by_time else "sent",
            "top_n": top_n,
            "k": k,
            "preset": preset or self.settings.query_preset,
            "capture_times": [f.capture_time for f in frames],
        }
        with transaction(db):
            track_id = track_store.insert_track(db, map_id=map_id, params=params)
            for index, frame in enumerate(frames):
                query_id = query_store.insert_query(
                    db, map_id=map_id, params=frame.params, image_path=frame.key, sha256=frame.sha256
                )
                track_store.attach_frame(db, query_id, track_id, index)
                if frame.received is not None:
                    frame.received.move_to(frame.key)  # after the insert took the query-photo lock
            job_id = job_store.enqueue_job(
                db,
                LOCATE_TRACK,
                LocateTrackPayload(track_id=track_id, map_id=map_id),
                max_attempts=self.settings.job_max_attempts,
                map_id=map_id,
                max_queued=self.settings.max_queued_jobs,
            )
            track_store.set_track_job(db, track_id, job_id)
        self.publisher.publish(db, [job_id])
        return track_id, job_id
