"""The durable job table: enqueue, atomic claim with a lease, heartbeat, finish, retry.

Lifecycle: ``queued`` -> ``running`` (claimed, leased) -> ``done`` | ``failed`` (attempts used up)
| back to ``queued`` (a failed attempt with attempts left, or a worker that released it on
shutdown). A ``running`` job whose lease expired (its worker died) is claimable again. Jobs of a
deleted reference or map that are still ``queued`` become ``cancelled``.

All writes check ``lease_owner`` so that a worker whose lease was taken over cannot overwrite
the new owner's outcome.
"""

from __future__ import annotations

import json
import time
from typing import Any

import sqlite_utils

from db.connection import transaction

JOB_STATUSES = ("queued", "running", "done", "failed", "cancelled")
LABEL_REFERENCE = "label_reference"
LOCALIZE_QUERY = "localize_query"
"""Job kind enqueued for each new reference; payload ``{"reference_id": int, "map_id": int}``."""
DEFAULT_MAX_ATTEMPTS = 3


def _decode(row: dict[str, Any] | None) -> dict[str, Any] | None:
    if row is None:
        return None
    row = dict(row)
    row["payload"] = json.loads(row["payload"]) if row.get("payload") else {}
    row["result"] = json.loads(row["result"]) if row.get("result") else None
    return row


def enqueue_job(
    db: sqlite_utils.Database,
    kind: str,
    payload: dict[str, Any],
    *,
    max_attempts: int = DEFAULT_MAX_ATTEMPTS,
    priority: int = 0,
    map_id: int | None = None,
    reference_id: int | None = None,
) -> int:
    """Add a queued job; returns its id. Joins the caller's transaction if one is open."""
    now = time.time()
    cursor = db.execute(
        "INSERT INTO jobs (kind, payload, status, priority, max_attempts, map_id, reference_id,"
        " created_at, updated_at) VALUES (?, ?, 'queued', ?, ?, ?, ?, ?, ?)",
        (kind, json.dumps(payload), priority, max_attempts, map_id, reference_id, now, now),
    )
    return int(cursor.lastrowid)


def get_job(db: sqlite_utils.Database, job_id: int) -> dict[str, Any] | None:
    """One job as a dict (payload and result decoded), or None."""
    rows = list(db.query("SELECT * FROM jobs WHERE id = ?", (job_id,)))
    return _decode(rows[0]) if rows else None


def list_jobs(db: sqlite_utils.Database, *, status: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
    """Most recent jobs first, optionally of one status."""
    if status is None:
        rows = db.query("SELECT * FROM jobs ORDER BY id DESC LIMIT ?", (limit,))
    else:
        rows = db.query("SELECT * FROM jobs WHERE status = ? ORDER BY id DESC LIMIT ?", (status, limit))
    return [_decode(row) for row in rows]  # type: ignore[misc]


def claim_job(
    db: sqlite_utils.Database, worker_id: str, lease_s: float, kinds: list[str] | None = None
) -> dict[str, Any] | None:
    """Atomically take the next runnable job (queued and due, or running with an expired lease).

    One ``UPDATE ... WHERE id = (SELECT ...) RETURNING *`` inside ``BEGIN IMMEDIATE``: two workers
    can never claim the same job. Expired jobs whose attempts are used up are failed first.
    """
    now = time.time()
    kind_filter = ""
    params: list[Any] = []
    if kinds:
        kind_filter = f" AND kind IN ({', '.join('?' for _ in kinds)})"
        params = list(kinds)
    due = db.execute(
        "SELECT EXISTS (SELECT 1 FROM jobs WHERE"
        " ((status = 'queued' AND run_after <= ?) OR (status = 'running' AND lease_expires_at < ?))"
        f"{kind_filter})",
        [now, now, *params],
    ).fetchone()[0]
    if not due:  # cheap read first: idle workers do not take the write lock
        return None
    with transaction(db):
        db.execute(
            "UPDATE jobs SET status = 'failed', finished_at = ?, updated_at = ?, lease_owner = NULL,"
            " error = COALESCE(error || char(10), '') || 'worker lost: lease expired after attempt '"
            " || attempts || ' of ' || max_attempts"
            " WHERE status = 'running' AND lease_expires_at < ? AND attempts >= max_attempts",
            (now, now, now),
        )
        row = db.execute(
            "UPDATE jobs SET status = 'running', attempts = attempts + 1, lease_owner = ?,"
            " lease_expires_at = ?, heartbeat_at = ?, started_at = ?, updated_at = ?"
            " WHERE id = (SELECT id FROM jobs WHERE"
            " ((status = 'queued' AND run_after <= ?) OR (status = 'running' AND lease_expires_at < ?))"
            f"{kind_filter} ORDER BY priority DESC, id LIMIT 1)"
            " RETURNING *",
            [worker_id, now + lease_s, now, now, now, now, now, *params],
        )
        columns = [d[0] for d in row.description]
        rows = row.fetchall()
        fetched = rows[0] if rows else None
    return _decode(dict(zip(columns, fetched, strict=True))) if fetched else None


def heartbeat_job(db: sqlite_utils.Database, job_id: int, worker_id: str, lease_s: float) -> bool:
    """Extend the lease; False when this worker no longer owns the job."""
    now = time.time()
    cursor = db.execute(
        "UPDATE jobs SET lease_expires_at = ?, heartbeat_at = ?, updated_at = ?"
        " WHERE id = ? AND lease_owner = ? AND status = 'running'",
        (now + lease_s, now, now, job_id, worker_id),
    )
    return cursor.rowcount == 1


def complete_job(db: sqlite_utils.Database, job_id: int, worker_id: str, result: dict[str, Any]) -> bool:
    """Mark done with its result; False when the lease was lost (the result is then dropped)."""
    now = time.time()
    cursor = db.execute(
        "UPDATE jobs SET status = 'done', result = ?, finished_at = ?, updated_at = ?,"
        " lease_expires_at = NULL WHERE id = ? AND lease_owner = ? AND status = 'running'",
        (json.dumps(result), now, now, job_id, worker_id),
    )
    return cursor.rowcount == 1


def fail_job(
    db: sqlite_utils.Database,
    job_id: int,
    worker_id: str,
    error: str,
    *,
    retry_delay_s: float = 1.0,
    permanent: bool = False,
) -> str | None:
    """Record a failed attempt: back to ``queued`` (due after ``retry_delay_s``) while attempts
    remain and the error is not ``permanent``, else ``failed``. The error text is kept either way.
    Returns the new status, or None when the lease was lost."""
    now = time.time()
    retry = "(? = 0 AND attempts < max_attempts)"
    rows = db.execute(
        f"UPDATE jobs SET status = CASE WHEN {retry} THEN 'queued' ELSE 'failed' END,"
        " run_after = ?, error = ?, updated_at = ?, lease_expires_at = NULL,"
        f" finished_at = CASE WHEN {retry} THEN NULL ELSE ? END"
        " WHERE id = ? AND lease_owner = ? AND status = 'running' RETURNING status",
        (int(permanent), now + retry_delay_s, error, now, int(permanent), now, job_id, worker_id),
    ).fetchall()
    return rows[0][0] if rows else None


def release_job(db: sqlite_utils.Database, job_id: int, worker_id: str) -> bool:
    """Give a running job back to the queue without counting the attempt (graceful shutdown)."""
    now = time.time()
    cursor = db.execute(
        "UPDATE jobs SET status = 'queued', attempts = MAX(attempts - 1, 0), lease_owner = NULL,"
        " lease_expires_at = NULL, run_after = ?, updated_at = ?"
        " WHERE id = ? AND lease_owner = ? AND status = 'running'",
        (now, now, job_id, worker_id),
    )
    return cursor.rowcount == 1


def cancel_queued_jobs(db: sqlite_utils.Database, *, map_id: int | None = None, reference_id: int | None = None) -> int:
    """Cancel the queued jobs of a map or reference being deleted; returns how many."""
    now = time.time()
    if reference_id is not None:
        where, value = "reference_id = ?", reference_id
    elif map_id is not None:
        where, value = "map_id = ?", map_id
    else:
        raise ValueError("map_id or reference_id is required")
    cursor = db.execute(
        f"UPDATE jobs SET status = 'cancelled', updated_at = ?, finished_at = ? WHERE {where} AND status = 'queued'",
        (now, now, value),
    )
    return cursor.rowcount


# --- worker registry (for /readyz and for finding who runs what) ---------------------------------


def register_worker(db: sqlite_utils.Database, worker_id: str, pid: int, hostname: str) -> None:
    """Record a worker process as alive."""
    now = time.time()
    db.execute(
        "INSERT OR REPLACE INTO workers (worker_id, pid, hostname, started_at, heartbeat_at) VALUES (?, ?, ?, ?, ?)",
        (worker_id, pid, hostname, now, now),
    )


def heartbeat_worker(db: sqlite_utils.Database, worker_id: str, current_job_id: int | None) -> None:
    """Refresh the worker's liveness and current job."""
    db.execute(
        "UPDATE workers SET heartbeat_at = ?, current_job_id = ? WHERE worker_id = ?",
        (time.time(), current_job_id, worker_id),
    )


def stop_worker(db: sqlite_utils.Database, worker_id: str) -> None:
    """Mark a worker as stopped (clean exit)."""
    db.execute(
        "UPDATE workers SET stopped_at = ?, current_job_id = NULL WHERE worker_id = ?",
        (time.time(), worker_id),
    )


def live_workers(db: sqlite_utils.Database, within_s: float) -> list[dict[str, Any]]:
    """Workers not stopped whose heartbeat is at most ``within_s`` old."""
    return list(
        db.query(
            "SELECT * FROM workers WHERE stopped_at IS NULL AND heartbeat_at >= ? ORDER BY started_at",
            (time.time() - within_s,),
        )
    )
