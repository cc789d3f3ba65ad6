"""The photo-upload use-case that references and queries share (:class:`PhotoIntake`).

A photo upload, a reference or a query, goes through :meth:`PhotoIntake.accept`: look the map up (404),
check the form, receive the photo (413 over the size limit), check it by its content (415, 413, 422) and
against the map, then store the photo, its row and its job in one transaction and hand the job to the
workers once committed. What differs is a subclass's: the form checks, what is stored of the photo, the
row, the job's kind and payload, and (references) the duplicate check: :mod:`service.intake_references`,
:mod:`service.intake_queries` (and a track's frames, :mod:`service.intake_tracks`). Routes call the use-cases;
no use-case imports a route module.

Decision (sync or async routes): both upload routes are ``async`` and run this blocking use-case in a worker
thread (``fastapi.concurrency.run_in_threadpool``) with its own database connection. The query route must be
async to wait for its answer on the event loop without holding a thread (:mod:`service.waiting`); the
reference route follows it so that the two uploads have one shape. No blocking work (file, image or
database) runs on the event loop.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

from fastapi import UploadFile

from contracts.jobs import JobPayload
from contracts.settings import Settings
from db import Database, transaction
from db import jobs as job_store
from db.files import FileStore
from db.rows import MapRow
from service.deps import open_db
from service.images import ImageInfo, validate_image
from service.tenancy import require_ready_map
from service.uploads import ReceivedFile, received_upload
from workers.broker import JobPublisher


@dataclass(frozen=True)
class Accepted:
    """What an upload stored: its row's id, its job's (None for a duplicate: nothing queued), the photo's sha256."""

    subject_id: int
    job_id: int | None
    sha256: str
    duplicate: bool = False


class PhotoIntake(ABC):
    """The photo-upload use-case of one map; subclasses say what a reference or a query stores.

    Blocking (file, image and database work): run :meth:`accept` in a worker thread.
    """

    folder: str
    """The store folder of these photos (``images`` for references, ``queries``)."""
    kind: str
    """The kind of the job each upload queues."""

    def __init__(self, settings: Settings, store: FileStore, publisher: JobPublisher) -> None:
        self.settings = settings
        self.store = store
        self.publisher = publisher

    def check_form(self) -> None:  # noqa: B027  # a hook: nothing to check by default
        """Check the form's fields before the photo is received (422)."""

    @abstractmethod
    def check_photo(self, map_row: MapRow, info: ImageInfo) -> None:
        """Check the photo (its EXIF) and the form against the map (422), keeping what :meth:`insert` stores."""

    def existing(self, db: Database, map_id: int, sha256: str) -> int | None:
        """The id of the row that already holds this photo (then nothing is stored), inside the transaction."""
        return None

    @abstractmethod
    def insert(self, db: Database, map_id: int, key: str, received: ReceivedFile, info: ImageInfo) -> int:
        """Insert the row of a new upload stored at ``key``; returns its id (inside the transaction)."""

    @abstractmethod
    def payload(self, subject_id: int, map_id: int) -> JobPayload:
        """The payload of the job that processes row ``subject_id``."""

    @abstractmethod
    def link(self, db: Database, subject_id: int, job_id: int) -> None:
        """Record the row's job (inside the transaction)."""

    def job_reference_id(self, subject_id: int) -> int | None:
        """The reference the job belongs to (its deletion cancels the job), if any."""
        return None

    def accept(self, map_id: int, image: UploadFile, tenant: str | None) -> Accepted:
        """Check and store an upload of map ``map_id`` (of ``tenant``, else 404) with its job; see the module."""
        settings = self.settings
        db = open_db(settings)
        try:
            map_row = require_ready_map(db, map_id, tenant)
            self.check_form()
            with received_upload(image, self.store, settings.max_image_bytes, "the image") as received:
                info = validate_image(
                    received.path, max_pixels=settings.max_image_pixels, min_side=settings.min_image_side
                )
                self.check_photo(map_row, info)
                key = f"{self.folder}/{map_id}/{received.sha256}.{info.extension}"
                with transaction(db):  # the duplicate check, the photo, its row and its job are one unit
                    existing = self.existing(db, map_id, received.sha256)
                    if existing is not None:
                        return Accepted(existing, None, received.sha256, duplicate=True)
                    subject_id = self.insert(db, map_id, key, received, info)
                    received.move_to(key)  # after the insert took its locks
                    job_id = job_store.enqueue_job(
                        db,
                        self.kind,
                        self.payload(subject_id, map_id),
                        max_attempts=settings.job_max_attempts,
                        map_id=map_id,
                        reference_id=self.job_reference_id(subject_id),
                        max_queued=settings.max_queued_jobs,
                    )
                    self.link(db, subject_id, job_id)
            self.publisher.publish(db, [job_id])
            return Accepted(subject_id, job_id, received.sha256)
        finally:
            db.close()
