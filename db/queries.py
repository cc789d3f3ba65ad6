"""Query records: parameters, status and the JSON answer.

``params`` is a :class:`contracts.queries.QueryParams`'s JSON; the method fills ``result`` with a
:class:`contracts.answers.QueryResult`'s JSON form.
"""

from __future__ import annotations

import json
import time
from typing import Any, cast

from contracts.queries import QueryParams
from db.connection import Database
from db.jobs import cancel_queued_jobs
from db.rows import QueryRow

QUERY_PHOTOS_LOCK = "geoloc:query-photos"
"""Held by a transaction that stores a query photo or checks which photos no query uses any more."""


def decode_query_row(row: dict[str, Any]) -> QueryRow:
    """A query row as stored to its typed form (params and result decoded)."""
    row = dict(row)
    row["params"] = QueryParams.from_json(json.loads(row["params"] or "{}"))
    row["result"] = json.loads(row["result"]) if row.get("result") else None
    return cast(QueryRow, row)


def insert_query(
    db: Database,
    *,
    map_id: int,
    params: QueryParams,
    image_path: str | None = None,
    sha256: str | None = None,
) -> int:
    """Insert a queued query; returns its id.

    Call inside the transaction that puts its photo in the store (it takes :data:`QUERY_PHOTOS_LOCK`, so
    retention cannot remove that photo meanwhile).
    """
    db.lock(QUERY_PHOTOS_LOCK)
    now = time.time()
    return db.insert_returning_id(
        "INSERT INTO queries (map_id, image_path, sha256, params, status, created_at, updated_at)"
        " VALUES (?, ?, ?, ?, 'queued', ?, ?)",
        (map_id, image_path, sha256, json.dumps(params.to_json()), now, now),
    )


def set_query_job(db: Database, query_id: int, job_id: int) -> None:
    """Link a query to the job that answers it."""
    db.execute("UPDATE queries SET job_id = ?, updated_at = ? WHERE id = ?", (job_id, time.time(), query_id))


def get_query(db: Database, query_id: int) -> QueryRow | None:
    """One query (params and result decoded), or None."""
    rows = list(db.query("SELECT * FROM queries WHERE id = ?", (query_id,)))
    return decode_query_row(rows[0]) if rows else None


def update_query_result(
    db: Database,
    query_id: int,
    *,
    status: str,
    result: dict[str, Any] | None = None,
    error: str | None = None,
) -> bool:
    """Write a query's outcome; False if it no longer exists."""
    cursor = db.execute(
        "UPDATE queries SET status = ?, result = ?, error = ?, updated_at = ? WHERE id = ?",
        (status, json.dumps(result) if result is not None else None, error, time.time(), query_id),
    )
    return cursor.rowcount == 1


def delete_query(db: Database, query_id: int) -> QueryRow | None:
    """Delete a query and cancel its job if still queued.

    Returns its row (``image_path`` to remove after commit), or None.
    """
    row = get_query(db, query_id)
    if row is not None:
        db.execute("DELETE FROM queries WHERE id = ?", (query_id,))
        if row["job_id"] is not None:  # else a worker would take it and fail it: "query N no longer exists"
            cancel_queued_jobs(db, job_id=row["job_id"])
    return row


def delete_expired_queries(db: Database, cutoff: float, *, limit: int = 500) -> list[str | None]:
    """Delete up to ``limit`` finished queries created before ``cutoff`` (Unix s) with their jobs.

    A query is finished when its row says ``done``/``failed`` or its job is ``done``, ``failed`` or
    ``cancelled``; queries still waiting or running are kept whatever their age. A track's frames go with
    their track (:func:`db.tracks.delete_expired_tracks`). References are not touched. Call inside a
    transaction; returns the image path of each deleted query (remove the
    files no row refers to any more after commit, see :func:`unreferenced_images`).
    """
    rows = db.execute(
        "SELECT q.id, q.image_path, q.job_id FROM queries q LEFT JOIN jobs j ON j.id = q.job_id"
        " WHERE q.created_at < ? AND q.track_id IS NULL"
        " AND (q.status IN ('done', 'failed') OR j.status IN ('done', 'failed', 'cancelled')"
        " OR j.id IS NULL) ORDER BY q.id LIMIT ?",
        (cutoff, limit),
    ).fetchall()
    if not rows:
        return []
    query_ids = [row[0] for row in rows]
    job_ids = [row[2] for row in rows if row[2] is not None]
    marks = ", ".join("?" for _ in query_ids)
    db.execute(f"DELETE FROM queries WHERE id IN ({marks})", query_ids)
    if job_ids:
        job_marks = ", ".join("?" for _ in job_ids)
        db.execute(f"DELETE FROM jobs WHERE id IN ({job_marks}) AND status IN ('done', 'failed', 'cancelled')", job_ids)
    return [row[1] for row in rows]


def unreferenced_images(db: Database, paths: list[str | None]) -> list[str]:
    """The paths among ``paths`` that no query refers to (the same photo asked twice shares one file).

    Check and remove inside one transaction (this takes :data:`QUERY_PHOTOS_LOCK`): an upload puts its
    file in place inside its own transaction under the same lock, so it cannot slip in between the check
    and the removal.
    """
    db.lock(QUERY_PHOTOS_LOCK)
    wanted = sorted({path for path in paths if path})
    return [
        path for path in wanted if db.execute("SELECT 1 FROM queries WHERE image_path = ?", (path,)).fetchone() is None
    ]
