"""Retention: the workers delete finished queries and tracks (photos, answers, jobs) older than the retention.

The retention is ``GEOLOC_QUERY_RETENTION_S``.
Every worker runs :func:`purge_expired_queries` from its loop every :func:`purge_interval_s`; the
deletes are transactional, so workers running it at the same time never delete a row twice, and a
photo file is removed only when no remaining query refers to it. Queries still waiting or running
are kept whatever their age. References (photos, labels, index) are never deleted implicitly: only
``DELETE /v1/references/{id}`` or deleting their map removes them.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from db import Database, transaction
from db import queries as query_store
from db import tracks as track_store
from db.files import FileStore, open_store

log = logging.getLogger("geoloc.worker")

BATCH = 500
"""Queries deleted per transaction (short write locks, so the API and other workers are not held up)."""
TRACK_BATCH = 50
"""Tracks (each with up to ``GEOLOC_MAX_TRACK_FRAMES`` frames) deleted per transaction."""
MAX_INTERVAL_S = 60.0


def purge_interval_s(retention_s: float) -> float:
    """How often a worker looks for expired queries: a tenth of the retention, between 1 s and a minute."""
    return min(MAX_INTERVAL_S, max(1.0, retention_s / 10.0))


def purge_expired_queries(
    db: Database, store: FileStore | Path, retention_s: float, *, now: float | None = None
) -> int:
    """Delete finished queries and tracks (with their frames) older than the retention; returns how many rows.

    A track counts once however many frames it has; a frame goes with its track, never alone.

    A query goes when it was created more than ``retention_s`` seconds before ``now`` (Unix s, default the
    current time); its photo is removed from ``store`` (or the store folder at that path) once no query uses it.
    """
    if isinstance(store, Path):
        store = open_store(store)
    cutoff = (time.time() if now is None else now) - retention_s
    deleted = 0
    while True:
        with transaction(db):
            paths = query_store.delete_expired_queries(db, cutoff, limit=BATCH)
        deleted += len(paths)
        _remove_unused(db, store, paths)
        if len(paths) < BATCH:
            break
    tracks = 0
    while True:
        with transaction(db):
            count, paths = track_store.delete_expired_tracks(db, cutoff, limit=TRACK_BATCH)
        tracks += count
        _remove_unused(db, store, paths)
        if count < TRACK_BATCH:
            break
    if deleted or tracks:
        log.info("retention: deleted %d queries and %d tracks older than %.0f s", deleted, tracks, retention_s)
    return deleted + tracks


def _remove_unused(db: Database, store: FileStore, paths: list[str | None]) -> None:
    """Remove the photos among ``paths`` that no query uses any more."""
    if paths:
        with transaction(db):  # under the query-photo lock: no upload re-places a photo between check and removal
            store.delete(*query_store.unreferenced_images(db, paths))
