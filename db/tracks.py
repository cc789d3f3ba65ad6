"""Track records: a walk of query photos located together.

Decision (where a track's frames live): each frame is a row of ``queries`` with the track's ``track_id`` and its
``frame_index`` (from 0), not a table of its own. A frame's photo, parameters (its own priors) and answer are then
stored, served (``GET /v1/queries/{id}``), deleted and pruned the way a query's are, and the photo store's
"remove a file no query uses" rule covers frames too. A frame's query row shares the track's job (``job_id``), so
its status follows the track's. ``tracks`` holds the track's parameters (JSON: order, answer size, preset, the
frames' capture times) and its answer (a :class:`contracts.answers.TrackResult`'s JSON). Retention and deletion
take a track with its frames; a lone query's retention (:func:`db.queries.delete_expired_queries`) skips frames.
"""

from __future__ import annotations

import json
import time
from typing import Any, cast

from db.connection import Database
from db.jobs import cancel_queued_jobs
from db.queries import decode_query_row
from db.rows import QueryRow, TrackRow


def _decode(row: dict[str, Any]) -> TrackRow:
    row = dict(row)
    row["params"] = json.loads(row["params"] or "{}")
    row["result"] = json.loads(row["result"]) if row.get("result") else None
    return cast(TrackRow, row)


def insert_track(db: Database, *, map_id: int, params: dict[str, Any]) -> int:
    """Insert a queued track of map ``map_id`` with its parameters (JSON-ready); returns its id."""
    now = time.time()
    return db.insert_returning_id(
        "INSERT INTO tracks (map_id, params, status, created_at, updated_at) VALUES (?, ?, 'queued', ?, ?)",
        (map_id, json.dumps(params), now, now),
    )


def attach_frame(db: Database, query_id: int, track_id: int, frame_index: int) -> None:
    """Make query ``query_id`` frame ``frame_index`` of track ``track_id``."""
    db.execute("UPDATE queries SET track_id = ?, frame_index = ? WHERE id = ?", (track_id, frame_index, query_id))


def set_track_job(db: Database, track_id: int, job_id: int) -> None:
    """Link a track and each of its frames to the job that locates them."""
    now = time.time()
    db.execute("UPDATE tracks SET job_id = ?, updated_at = ? WHERE id = ?", (job_id, now, track_id))
    db.execute("UPDATE queries SET job_id = ?, updated_at = ? WHERE track_id = ?", (job_id, now, track_id))


def get_track(db: Database, track_id: int) -> TrackRow | None:
    """One track (params and result decoded), or None."""
    rows = list(db.query("SELECT * FROM tracks WHERE id = ?", (track_id,)))
    return _decode(rows[0]) if rows else None


def track_frames(db: Database, track_id: int) -> list[QueryRow]:
    """The frames of a track (their query rows), in frame order."""
    rows = db.query("SELECT * FROM queries WHERE track_id = ? ORDER BY frame_index", (track_id,))
    return [decode_query_row(row) for row in rows]


def update_track_result(
    db: Database, track_id: int, *, status: str, result: dict[str, Any] | None = None, error: str | None = None
) -> bool:
    """Write a track's outcome; False if it no longer exists."""
    cursor = db.execute(
        "UPDATE tracks SET status = ?, result = ?, error = ?, updated_at = ? WHERE id = ?",
        (status, json.dumps(result) if result is not None else None, error, time.time(), track_id),
    )
    return cursor.rowcount == 1


def _delete_tracks(db: Database, track_ids: list[int]) -> list[str | None]:
    """Delete tracks and their frames' query rows; returns the frames' image paths."""
    marks = ", ".join("?" for _ in track_ids)
    paths = [
        row[0]
        for row in db.execute(f"SELECT image_path FROM queries WHERE track_id IN ({marks})", track_ids).fetchall()
    ]
    db.execute(f"DELETE FROM queries WHERE track_id IN ({marks})", track_ids)
    db.execute(f"DELETE FROM tracks WHERE id IN ({marks})", track_ids)
    return paths


def delete_track(db: Database, track_id: int) -> list[str | None] | None:
    """Delete a track with its frames (inside a transaction) and cancel its job if still queued.

    Returns the frames' image paths to remove after, or None.
    """
    track = get_track(db, track_id)
    if track is None:
        return None
    if track["job_id"] is not None:
        cancel_queued_jobs(db, job_id=track["job_id"])
    return _delete_tracks(db, [track_id])


def delete_expired_tracks(db: Database, cutoff: float, *, limit: int = 100) -> tuple[int, list[str | None]]:
    """Delete up to ``limit`` finished tracks created before ``cutoff`` (Unix s), with their frames and jobs.

    Finished as a query is (:func:`db.queries.delete_expired_queries`): its row says done/failed or its job is
    final (or gone). Call inside a transaction; returns how many tracks went and their frames' image paths
    (remove those no query uses any more after commit: :func:`db.queries.unreferenced_images`).
    """
    rows = db.execute(
        "SELECT t.id, t.job_id FROM tracks t LEFT JOIN jobs j ON j.id = t.job_id"
        " WHERE t.created_at < ? AND (t.status IN ('done', 'failed') OR j.status IN ('done', 'failed', 'cancelled')"
        " OR j.id IS NULL) ORDER BY t.id LIMIT ?",
        (cutoff, limit),
    ).fetchall()
    if not rows:
        return 0, []
    paths = _delete_tracks(db, [row[0] for row in rows])
    job_ids = [row[1] for row in rows if row[1] is not None]
    if job_ids:
        marks = ", ".join("?" for _ in job_ids)
        db.execute(f"DELETE FROM jobs WHERE id IN ({marks}) AND status IN ('done', 'failed', 'cancelled')", job_ids)
    return len(rows), paths
