"""The map-upload use-case: a map file checked and stored with its ``load_map`` job.

The file is received (413 over the size limit), checked for what it inflates to (413) and what it is by its
content (422), and stored with a ``queued`` row and its job in one transaction, unless the same file with the same
read options is already one of the tenant's maps. The parse itself is the job's (:mod:`workers.map_handlers`).
Routes call this module; it imports no route module.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from fastapi import UploadFile

from contracts.jobs import LOAD_MAP, LoadMapPayload
from contracts.settings import Settings
from db import jobs as job_store
from db import maps as map_store
from db import transaction
from db.files import FileStore
from geoloc.maps import MapLoadError, MapReadOptions
from geoloc.maps.guard import DecompressedTooLargeError, check_decompressed_size, public_message, public_name
from geoloc.maps.sniff import sniff_format
from service.deps import open_db
from service.errors import ApiError
from service.uploads import received_upload
from workers.broker import JobPublisher

log = logging.getLogger("geoloc.api")

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


@dataclass(frozen=True)
class MapForm:
    """The form fields of a map upload, as sent (the file aside); blank read options mean the default."""

    name: str
    layer: str | None
    name_attribute: str | None
    height_attribute: str | None
    levels_attribute: str | None
    crs: str | None
    attribution: str | None
    wait_s: float

    def read_options(self) -> MapReadOptions:
        """The read-option fields as ``MapReadOptions`` (blank fields mean the default)."""
        given = {
            "layer": self.layer,
            "name_attribute": self.name_attribute,
            "height_attribute": self.height_attribute,
            "levels_attribute": self.levels_attribute,
            "crs": self.crs,
        }
        return MapReadOptions(**{k: v.strip() for k, v in given.items() if v is not None and v.strip()})


@dataclass(frozen=True)
class MapUpload:
    """A map upload to accept: its file, name, read options, stated attribution (None: the default), tenant."""

    file: UploadFile
    name: str
    options: MapReadOptions
    attribution: str | None
    tenant: str | None


@dataclass(frozen=True)
class AcceptedMap:
    """What a map upload stored: the map's id, its job's (None for a duplicate), whether it was one."""

    map_id: int
    job_id: int | None
    duplicate: bool


def accept_map(settings: Settings, store: FileStore, publisher: JobPublisher, upload: MapUpload) -> AcceptedMap:
    """Receive the file (413), check what it inflates to (413) and what it is (422), store it with its job.

    The map is ``upload.tenant``'s (the duplicate check looks at its maps only).

    Blocking: run in a worker thread. The parse itself is the job's (:mod:`workers.map_handlers`).
    """
    read_options, tenant = upload.options.as_dict(), upload.tenant
    db = open_db(settings)
    try:
        with received_upload(upload.file, store, settings.max_map_bytes, "the map file") as received:
            shown_name = public_name(received.filename)
            existing = map_store.find_map_by_sha256(db, received.sha256, read_options, tenant)
            if existing is not None:
                return AcceptedMap(existing["id"], None, duplicate=True)
            try:
                check_decompressed_size(received.path, settings.max_decompressed_bytes, shown_name)
                source_format = sniff_format(received.path)
            except DecompressedTooLargeError as exc:
                raise ApiError(413, exc.code, str(exc), exc.details) from exc
            except MapLoadError as exc:
                raise ApiError(422, exc.code, public_message(str(exc), received.path, shown_name), exc.details) from exc
            relative = f"maps/{received.sha256}{SOURCE_EXTENSIONS.get(source_format, '.map')}"
            with transaction(db):  # the duplicate check, the row and its job are atomic
                db.lock(f"geoloc:map:{received.sha256}")  # the same file sent twice at once
                existing = map_store.find_map_by_sha256(db, received.sha256, read_options, tenant)
                if existing is not None:
                    return AcceptedMap(existing["id"], None, duplicate=True)
                received.move_to(relative)
                map_id = map_store.insert_pending_map(
                    db,
                    name=upload.name,
                    source_filename=received.filename or "upload",
                    source_format=source_format,
                    source_path=relative,
                    sha256=received.sha256,
                    size_bytes=received.size_bytes,
                    read_options=read_options,
                    attribution=upload.attribution,
                    tenant=tenant,
                )
                job_id = job_store.enqueue_job(
                    db,
                    LOAD_MAP,
                    LoadMapPayload(map_id=map_id),
                    max_attempts=settings.job_max_attempts,
                    map_id=map_id,
                    max_queued=settings.max_queued_jobs,
                )
                map_store.link_map_job(db, map_id, job_id)
        publisher.publish(db, [job_id])
        log.info("map %d stored, queued as job %d", map_id, job_id)
        return AcceptedMap(map_id, job_id, duplicate=False)
    finally:
        db.close()
