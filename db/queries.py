"""Query records: parameters, status and the JSON answer (the method fills ``result``)."""

from __future__ import annotations

import json
import time
from typing import Any

import sqlite_utils


def _decode(row: dict[str, Any]) -> dict[str, Any]:
    row = dict(row)
    row["params"] = json.loads(row["params"] or "{}")
    row["result"] = json.loads(row["result"]) if row.get("result") else None
    return row


def insert_query(
    db: sqlite_utils.Database,
    *,
    map_id: int,
    params: dict[str, Any],
    image_path: str | None = None,
    sha256: str | None = None,
) -> int:
    """Insert a queued query; returns its id."""
    now = time.time()
    cursor = db.execute(
        "INSERT INTO queries (map_id, image_path, sha256, params, status, created_at, updated_at)"
        " VALUES (?, ?, ?, ?, 'queued', ?, ?)",
        (map_id, image_path, sha256, json.dumps(params), now, now),
    )
    return int(cursor.lastrowid)


def set_query_job(db: sqlite_utils.Database, query_id: int, job_id: int) -> None:
    """Link a query to the job that answers it."""
    db.execute("UPDATE queries SET job_id = ?, updated_at = ? WHERE id = ?", (job_id, time.time(), query_id))


def get_query(db: sqlite_utils.Database, query_id: int) -> dict[str, Any] | None:
    """One query (params and result decoded), or None."""
    rows = list(db.query("SELECT * FROM queries WHERE id = ?", (query_id,)))
    return _decode(rows[0]) if rows else None


def update_query_result(
    db: sqlite_utils.Database,
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


def delete_query(db: sqlite_utils.Database, query_id: int) -> dict[str, Any] | None:
    """Delete a query; returns its row (``image_path`` to remove after commit), or None."""
    row = get_query(db, query_id)
    if row is not None:
        db.execute("DELETE FROM queries WHERE id = ?", (query_id,))
    return row
