"""The map job: an uploaded map file parsed into buildings and facades in the workers, not in the API (issue 22).

``POST /v1/maps`` stores the file (after the decompressed-size check, :mod:`geoloc.maps.guard`), inserts the
map's row as ``queued`` and queues a ``load_map`` job. The job reads the file with :func:`geoloc.maps.load_map`,
writing the parse's progress (elements read, buildings so far) on the map's row at most once every
:data:`PROGRESS_INTERVAL_S`, then stores the buildings and facades and marks the map ``done`` in one
transaction with replace semantics (a job run again after a worker crash leaves the same rows), writing the
loaded map's binary copy for the other jobs (:mod:`geoloc.maps.store`) on a thread beside the rows, finished
before that transaction commits.

A file that is not usable map data fails the map (``failed``, with the reader's reason: the user's file name
in it, never a server path) and the job at once, without retries: the same file fails the same way. A map
deleted while it is parsed: its queued job is cancelled by the delete; a running one finds the row gone when it
stores (:func:`db.maps.store_map_content`), stores nothing and removes the copy it wrote.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from contracts.jobs import LOAD_MAP, LoadMapPayload, LoadMapResult
from contracts.settings import data_dir, get_settings
from db import Database, transaction
from db import maps as map_store
from db.files import open_store
from geoloc.maps import (
    CityMap,
    MapLoadError,
    MapReadOptions,
    load_map,
    map_cache_dir,
    map_cache_path,
    remove_cached_map,
    save_city_map,
)
from geoloc.maps.guard import public_message, public_name
from workers.handlers import PermanentJobError, register

log = logging.getLogger("geoloc.worker")

PROGRESS_INTERVAL_S = 1.0
"""Least time between two progress writes of one parse (the parser calls far more often)."""


class ProgressWriter:
    """The parse's progress callback: records (elements, buildings) on the map's row, at a bounded rate."""

    def __init__(self, db: Database, map_id: int, interval_s: float = PROGRESS_INTERVAL_S) -> None:
        self.db = db
        self.map_id = map_id
        self.interval_s = interval_s
        self._last = 0.0

    def __call__(self, elements: int, buildings: int) -> None:
        """Record the progress unless the last write is less than ``interval_s`` old."""
        now = time.monotonic()
        if now - self._last < self.interval_s:
            return
        self._last = now
        map_store.set_map_progress(self.db, self.map_id, elements, buildings)


@register(LOAD_MAP, LoadMapPayload)
def load_map_job(db: Database, payload: LoadMapPayload) -> LoadMapResult:
    """Parse map ``payload.map_id``'s stored file and store its buildings and facades; see the module."""
    row = map_store.get_map(db, payload.map_id)
    if row is None:
        raise PermanentJobError(f"map {payload.map_id} no longer exists")
    if row["status"] == "done":  # stored by an earlier attempt that crashed before the job was marked done
        return LoadMapResult(map_id=row["id"], buildings=row["building_count"], facades=row["facade_count"])
    source = open_store(get_settings().file_store_dir).local_path(row["source_path"])
    shown = public_name(row["source_filename"])
    options = MapReadOptions.from_dict(row["read_options"])
    try:
        city_map = load_map(source, options, progress=ProgressWriter(db, row["id"]))
        content = map_store.map_content_from_city_map(city_map)
    except Exception as exc:
        reason = _reason(exc, source, shown)
        code, details = (exc.code, exc.details) if isinstance(exc, MapLoadError) else ("invalid_map", {})
        with transaction(db):  # committed before the job fails (a failing attempt's writes may be rolled back)
            map_store.fail_map(db, row["id"], reason, code, details)
        raise PermanentJobError(reason) from None  # the same file fails the same way: no retries
    cache = map_cache_path(map_cache_dir(data_dir()), row["sha256"], options)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="map-copy") as copier, transaction(db):
        # The copy is written while the rows go in (its GEOS, numpy and file work release the GIL); it is
        # finished before the commit marks the map done, so a job that sees the map done finds its copy.
        copied = copier.submit(_save_copy, city_map, cache, row["id"])
        stored = map_store.store_map_content(db, row["id"], content)
        copied.result()
    if not stored:  # deleted while it was parsed: nothing stored, no copy left behind
        if map_store.find_map_by_sha256(db, row["sha256"], row["read_options"]) is None:
            remove_cached_map(map_cache_dir(data_dir()), row["sha256"], options)
        return LoadMapResult(map_id=row["id"], buildings=0, facades=0)
    log.info("map %d stored: %d buildings, %d facades", row["id"], len(content.buildings), len(city_map.facades))
    return LoadMapResult(map_id=row["id"], buildings=len(content.buildings), facades=len(city_map.facades))


def _reason(exc: Exception, path: Path, shown: str) -> str:
    """What to tell the user about a file that could not be read: the reader's reason, no server path."""
    if isinstance(exc, MapLoadError):
        return public_message(str(exc), path, shown)
    log.error("map file %s could not be read", shown, exc_info=exc)  # not foreseen: still the file's fault
    return public_message(f"{shown}: cannot read the map ({type(exc).__name__}: {exc})", path, shown)


def _save_copy(city_map: CityMap, cache: Path, map_id: int) -> None:
    """Write the loaded map's binary copy (a cache: a job that misses it parses the source again)."""
    try:
        save_city_map(city_map, cache)
    except OSError:
        log.warning("map %d: could not write its cached copy", map_id, exc_info=True)
