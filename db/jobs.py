"""The durable job table: enqueue, atomic claim with a lease, heartbeat, finish, retry.

Kinds, statuses and payload models are in :mod:`contracts.jobs`. Lifecycle: ``queued`` -> ``running``
(claimed, leased) -> ``done`` | ``failed`` (attempts used up) | back to ``queued`` (a failed attempt with
attempts left, or a worker that released it on shutdown). A ``running`` job whose lease expired (its worker
died) is claimable again. Jobs of a deleted reference or map that are still ``queued`` become ``cancelled``.

All writes check ``lease_owner`` so that a worker whose lease was taken over cannot overwrite
the new owner's outcome.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from typing import Any, cast, overload

from contracts.jobs import JobPayload
from contracts.logs import current_request_id
from db.connection import Database, transaction
from db.rows import JobRow, WorkerRow

DEFAULT_MAX_ATTEMPTS = 3
RETRY_AFTER_BOUNDS_S = (1, 120)
"""Smallest and largest ``Retry-After`` suggested when the queue is full."""
RETRY_AFTER_UNKNOWN_S = 10
"""``Retry-After`` when no job finished recently (nothing to estimate the drain rate from)."""
THROUGHPUT_SAMPLE = 20
"""How many of the most recently finished jobs estimate the queue's drain rate."""
ENQUEUE_LOCK = "geoloc:enqueue"
"""Lock taken by transactions that check the queue's depth before enqueueing (see :meth:`Database.lock`)."""
_CLAIMABLE = "((status = 'queued' AND run_after <= ?) OR (status = 'running' AND lease_expires_at < ?))"
"""A job a worker may take now: queued and due, or running with an expired lease (its worker died)."""


class QueueFullError(Exception):
    """The queue already holds ``limit`` waiting jobs: new work is refused until it drains.

    ``retry_after_s`` estimates when a slot frees up, from the rate at which recent jobs finished.
    """

    def __init__(self, depth: int, limit: int, retry_after_s: int) -> None:
        super().__init__(f"the job queue is full ({depth} jobs waiting, limit {limit}); retry in {retry_after_s} s")
        self.depth = depth
        self.limit = limit
        self.retry_after_s = retry_after_s


@overload
def _decode(row: dict[str, Any]) -> JobRow: ...
@overload
def _decode(row: None) -> None: ...
def _decode(row: dict[str, Any] | None) -> JobRow | None:
    if row is None:
        return None
    row = dict(row)
    row["payload"] = json.loads(row["payload"]) if row.get("payload") else {}
    row["result"] = json.loads(row["result"]) if row.get("result") else None
    return cast(JobRow, row)


def enqueue_job(
    db: Database,
    kind: str,
    payload: JobPayload,
    *,
    max_attempts: int = DEFAULT_MAX_ATTEMPTS,
    priority: int = 0,
    map_id: int | None = None,
    reference_id: int | None = None,
    max_queued: int | None = None,
    tenant: str | None = None,
    request_id: str | None = None,
) -> int:
    """Add a queued job; returns its id. Joins the caller's transaction if one is open.

    The payload is stored as the JSON of its model (:meth:`contracts.jobs.JobPayload.to_json`). The job's
    tenant (``jobs.tenant``, who may see it in the API) is ``tenant``, else its map's (None: untenanted). Its
    ``request_id`` is the one given, else the current request's or job's (:func:`contracts.logs.current_request_id`).

    With ``max_queued``, raise :class:`QueueFullError` instead when that many jobs already wait
    (inside the caller's transaction, under :data:`ENQUEUE_LOCK`, the count cannot change before the
    insert).
    """
    if max_queued is not None:
        db.lock(ENQUEUE_LOCK)
        check_queue_capacity(db, max_queued)
    if tenant is None and map_id is not None:
        row = db.execute("SELECT tenant FROM maps WHERE id = ?", (map_id,)).fetchone()
        tenant = row[0] if row is not None else None
    now = time.time()
    request_id = request_id or current_request_id()
    return db.insert_returning_id(
        "INSERT INTO jobs (kind, payload, status, priority, max_attempts, map_id, reference_id, tenant,"
        " request_id, created_at, updated_at) VALUES (?, ?, 'queued', ?, ?, ?, ?, ?, ?, ?, ?)",
        (kind, json.dumps(payload.to_json()), priority, max_attempts, map_id, reference_id, tenant, request_id)
        + (now, now),
    )


def has_queued_job(db: Database, kind: str, map_id: int) -> bool:
    """Whether a job of ``kind`` for map ``map_id`` waits in the queue (not yet claimed)."""
    row = db.execute(
        "SELECT 1 FROM jobs WHERE kind = ? AND map_id = ? AND status = 'queued' LIMIT 1", (kind, map_id)
    ).fetchone()
    return row is not None


def pending_job_count(db: Database, kind: str, map_id: int) -> int:
    """Jobs of ``kind`` for map ``map_id`` not yet finished (``queued`` or ``running``)."""
    row = db.execute(
        "SELECT COUNT(*) FROM jobs WHERE kind = ? AND map_id = ? AND status IN ('queued', 'running')", (kind, map_id)
    ).fetchone()
    return int(row[0])


def queue_depth(db: Database) -> int:
    """Jobs waiting to run (``queued``, including retries waiting for their delay)."""
    return int(db.execute("SELECT COUNT(*) FROM jobs WHERE status = 'queued'").fetchone()[0])


def check_queue_capacity(db: Database, max_queued: int) -> None:
    """Raise :class:`QueueFullError` when ``max_queued`` or more jobs are waiting.

    Called before accepting new work and again inside the transaction that enqueues it, so the
    queue never grows past ``max_queued`` however many requests arrive at once.
    """
    depth = queue_depth(db)
    if depth >= max_queued:
        raise QueueFullError(depth, max_queued, retry_after_s(db, depth - max_queued + 1))


def retry_after_s(db: Database, excess: int) -> int:
    """Seconds until ``excess`` queue slots are likely free, from the drain rate of recent jobs.

    The rate is the number of the last :data:`THROUGHPUT_SAMPLE` finished jobs over the time since
    the oldest of them finished (found by walking back from the newest ids, so no index is needed).
    """
    rows = db.execute(
        "SELECT finished_at FROM jobs WHERE status IN ('done', 'failed') AND finished_at IS NOT NULL"
        " ORDER BY id DESC LIMIT ?",
        (THROUGHPUT_SAMPLE,),
    ).fetchall()
    low, high = RETRY_AFTER_BOUNDS_S
    span_s = time.time() - min((row[0] for row in rows), default=time.time())
    if len(rows) < 2 or span_s <= 0:
        return RETRY_AFTER_UNKNOWN_S
    jobs_per_s = len(rows) / span_s
    return int(min(max(math.ceil(excess / jobs_per_s), low), high))


def job_statuses(db: Database, job_ids: list[int]) -> dict[int, str]:
    """The status of each of ``job_ids`` that exists (one query, for the API's waiters)."""
    if not job_ids:
        return {}
    marks = ", ".join("?" for _ in job_ids)
    rows = db.execute(f"SELECT id, status FROM jobs WHERE id IN ({marks})", list(job_ids)).fetchall()
    return {int(job_id): str(status) for job_id, status in rows}


def get_job(db: Database, job_id: int) -> JobRow | None:
    """One job as a dict (payload and result decoded), or None."""
    rows = list(db.query("SELECT * FROM jobs WHERE id = ?", (job_id,)))
    return _decode(rows[0]) if rows else None


def list_jobs(db: Database, *, status: str | None = None, limit: int = 100) -> list[JobRow]:
    """Most recent jobs first, optionally of one status."""
    if status is None:
        rows = db.query("SELECT * FROM jobs ORDER BY id DESC LIMIT ?", (limit,))
    else:
        rows = db.query("SELECT * FROM jobs WHERE status = ? ORDER BY id DESC LIMIT ?", (status, limit))
    return [_decode(row) for row in rows]


def fail_exhausted_jobs(db: Database, now: float) -> int:
    """Fail the running jobs whose lease expired with their attempts used up; returns how many.

    Their worker died on the last attempt: the job is not taken again. Runs inside the claim (and the
    reconciler's) transaction.
    """
    cursor = db.execute(
        "UPDATE jobs SET status = 'failed', finished_at = ?, updated_at = ?, lease_owner = NULL,"
        " error = COALESCE(error || ?, '') || 'worker lost: lease expired after attempt '"
        " || attempts || ' of ' || max_attempts"
        " WHERE status = 'running' AND lease_expires_at < ? AND attempts >= max_attempts",
        (now, now, "\n", now),
    )
    return int(cursor.rowcount)


def _claim(db: Database, where: str, params: list[Any], worker_id: str, lease_s: float) -> JobRow | None:
    """Take the first claimable job matching ``where`` (under the claim's transaction)."""
    now = time.time()
    with transaction(db):
        fail_exhausted_jobs(db, now)
        cursor = db.execute(
            "UPDATE jobs SET status = 'running', attempts = attempts + 1, lease_owner = ?,"
            " lease_expires_at = ?, heartbeat_at = ?, started_at = ?, updated_at = ?"
            f" WHERE id = (SELECT id FROM jobs WHERE {_CLAIMABLE}{where}"
            f" ORDER BY priority DESC, id LIMIT 1{db.skip_locked})"
            f" AND {_CLAIMABLE} RETURNING *",
            [worker_id, now + lease_s, now, now, now, now, now, *params, now, now],
        )
        columns = [d[0] for d in cursor.description]
        fetched = cursor.fetchone()
    return _decode(dict(zip(columns, fetched, strict=True))) if fetched else None


def claim_job(db: Database, worker_id: str, lease_s: float, kinds: list[str] | None = None) -> JobRow | None:
    """Atomically take the next runnable job (queued and due, or running with an expired lease).

    One ``UPDATE ... WHERE id = (SELECT ...) RETURNING *`` in a transaction: under SQLite's write lock,
    or with ``FOR UPDATE SKIP LOCKED`` and the condition checked again on the row in PostgreSQL, so two
    workers can never claim the same job. Expired jobs whose attempts are used up are failed first.
    """
    now = time.time()
    kind_filter = ""
    params: list[Any] = []
    if kinds:
        kind_filter = f" AND kind IN ({', '.join('?' for _ in kinds)})"
        params = list(kinds)
    due = db.execute(f"SELECT EXISTS (SELECT 1 FROM jobs WHERE {_CLAIMABLE}{kind_filter})", [now, now, *params])
    if not due.fetchone()[0]:  # cheap read first: idle workers do not take the write lock
        return None
    return _claim(db, kind_filter, params, worker_id, lease_s)


def claim_job_by_id(db: Database, job_id: int, worker_id: str, lease_s: float) -> JobRow | None:
    """Take job ``job_id`` if it is claimable now (the broker delivered its id); else None.

    None means another worker runs it (a duplicate delivery), it is finished, cancelled or gone, or it
    waits for its retry delay (the reconciler publishes it again when it is due).
    """
    return _claim(db, " AND id = ?", [job_id], worker_id, lease_s)


def heartbeat_job(db: Database, job_id: int, worker_id: str, lease_s: float) -> bool:
    """Extend the lease; False when this worker no longer owns the job."""
    now = time.time()
    cursor = db.execute(
        "UPDATE jobs SET lease_expires_at = ?, heartbeat_at = ?, updated_at = ?"
        " WHERE id = ? AND lease_owner = ? AND status = 'running'",
        (now + lease_s, now, now, job_id, worker_id),
    )
    return cursor.rowcount == 1


def complete_job(db: Database, job_id: int, worker_id: str, result: dict[str, Any]) -> bool:
    """Mark done with its result (JSON-ready); False when the lease was lost (the result is then dropped)."""
    now = time.time()
    cursor = db.execute(
        "UPDATE jobs SET status = 'done', result = ?, finished_at = ?, updated_at = ?,"
        " lease_expires_at = NULL WHERE id = ? AND lease_owner = ? AND status = 'running'",
        (json.dumps(result), now, now, job_id, worker_id),
    )
    return cursor.rowcount == 1


def fail_job(
    db: Database,
    job_id: int,
    worker_id: str,
    error: str,
    *,
    retry_delay_s: float = 1.0,
    permanent: bool = False,
) -> str | None:
    """Record a failed attempt; returns the new status, or None when the lease was lost.

    The job goes back to ``queued`` (due after ``retry_delay_s``) while attempts remain and the error
    is not ``permanent``, else to ``failed``. The error text is kept either way.
    """
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


def deleted_subject(db: Database, job: JobRow) -> str | None:
    """What of the job's subject was deleted (its map, its reference), or None while both exist.

    A job whose map or reference is gone cannot succeed on a retry, whatever error its attempt hit.
    """
    for column, table, what in (("reference_id", "reference_images", "reference"), ("map_id", "maps", "map")):
        subject_id = job["reference_id"] if column == "reference_id" else job["map_id"]
        if subject_id is None:
            continue
        if db.execute(f"SELECT 1 FROM {table} WHERE id = ?", (subject_id,)).fetchone() is None:
            return f"{what} {subject_id} was deleted"
    return None


def release_job(db: Database, job_id: int, worker_id: str) -> bool:
    """Give a running job back to the queue without counting the attempt (graceful shutdown)."""
    now = time.time()
    cursor = db.execute(
        "UPDATE jobs SET status = 'queued', attempts = CASE WHEN attempts > 0 THEN attempts - 1 ELSE 0 END,"
        " lease_owner = NULL,"
        " lease_expires_at = NULL, run_after = ?, updated_at = ?"
        " WHERE id = ? AND lease_owner = ? AND status = 'running'",
        (now, now, job_id, worker_id),
    )
    return cursor.rowcount == 1


def cancel_queued_jobs(
    db: Database, *, map_id: int | None = None, reference_id: int | None = None, job_id: int | None = None
) -> int:
    """Cancel the queued jobs of a map, reference, query or track being deleted; returns how many.

    A query's or a track's job is named by its ``job_id`` (the jobs table keeps no query or track id).
    """
    now = time.time()
    if job_id is not None:
        where, value = "id = ?", job_id
    elif reference_id is not None:
        where, value = "reference_id = ?", reference_id
    elif map_id is not None:
        where, value = "map_id = ?", map_id
    else:
        raise ValueError("map_id, reference_id or job_id is required")
    cursor = db.execute(
        f"UPDATE jobs SET status = 'cancelled', updated_at = ?, finished_at = ? WHERE {where} AND status = 'queued'",
        (now, now, value),
    )
    return cursor.rowcount


# --- publication to a broker (distributed profile) ------------------------------------------------


def mark_published(db: Database, job_ids: list[int], now: float | None = None) -> None:
    """Record that these jobs' ids were just handed to the broker."""
    if job_ids:
        marks = ", ".join("?" for _ in job_ids)
        db.execute(f"UPDATE jobs SET published_at = ? WHERE id IN ({marks})", [now or time.time(), *job_ids])


def mark_unpublished(db: Database, job_ids: list[int]) -> None:
    """Forget a publication that did not happen (the broker refused): the reconciler takes these again."""
    if job_ids:
        marks = ", ".join("?" for _ in job_ids)
        db.execute(f"UPDATE jobs SET published_at = NULL WHERE id IN ({marks})", list(job_ids))


def jobs_to_publish(
    db: Database, now: float, *, unpublished_grace_s: float, republish_before: float | None = None, limit: int = 500
) -> list[int]:
    """Claim the right to (re)publish claimable jobs that no message will bring to a worker; returns their ids.

    A claimable job (queued and due, or running with an expired lease) is taken when

    - it was never published and is older than ``unpublished_grace_s`` (the API crashed between its commit
      and the publish, or the broker refused the message);
    - it became claimable after its last publication (a retry whose delay passed; a lease that expired
      because its worker died);
    - with ``republish_before``, it was last published before that time (the caller saw the broker's
      queue empty: the message was lost with a broker restart).

    Their ``published_at`` is set in the same statement, so reconcilers running at once never take the
    same job. Call inside a transaction; publish the ids after it commits.
    """
    stale = " OR published_at < ?" if republish_before is not None else ""
    params: list[Any] = [now, now, now, now - unpublished_grace_s]
    if republish_before is not None:
        params.append(republish_before)
    rows = db.execute(
        f"UPDATE jobs SET published_at = ? WHERE id IN (SELECT id FROM jobs WHERE {_CLAIMABLE} AND ("
        " (published_at IS NULL AND created_at < ?)"
        " OR (status = 'queued' AND published_at < run_after)"
        f" OR (status = 'running' AND published_at < lease_expires_at){stale})"
        f" ORDER BY priority DESC, id LIMIT ?{db.skip_locked}) RETURNING id",
        [*params, limit],
    ).fetchall()
    return sorted(int(row[0]) for row in rows)


# --- worker registry (for /readyz and for finding who runs what) ---------------------------------


def register_worker(db: Database, worker_id: str, pid: int, hostname: str, kinds: Sequence[str] = ()) -> None:
    """Record a worker process as alive, with the job kinds it claims (empty: every kind)."""
    now = time.time()
    db.execute(
        "INSERT INTO workers (worker_id, pid, hostname, started_at, heartbeat_at, kinds) VALUES (?, ?, ?, ?, ?, ?)"
        " ON CONFLICT (worker_id) DO UPDATE SET pid = excluded.pid, hostname = excluded.hostname,"
        " started_at = excluded.started_at, heartbeat_at = excluded.heartbeat_at, stopped_at = NULL,"
        " current_job_id = NULL, kinds = excluded.kinds",
        (worker_id, pid, hostname, now, now, ",".join(kinds) or None),
    )


def heartbeat_worker(db: Database, worker_id: str, current_job_id: int | None) -> None:
    """Refresh the worker's liveness and current job."""
    db.execute(
        "UPDATE workers SET heartbeat_at = ?, current_job_id = ? WHERE worker_id = ?",
        (time.time(), current_job_id, worker_id),
    )


def stop_worker(db: Database, worker_id: str) -> None:
    """Mark a worker as stopped (clean exit)."""
    db.execute(
        "UPDATE workers SET stopped_at = ?, current_job_id = NULL WHERE worker_id = ?",
        (time.time(), worker_id),
    )


def claimed_kinds(worker: WorkerRow) -> tuple[str, ...]:
    """The job kinds a registered worker claims; empty: every kind."""
    return tuple(worker["kinds"].split(",")) if worker["kinds"] else ()


def live_workers(db: Database, within_s: float) -> list[WorkerRow]:
    """Workers not stopped whose heartbeat is at most ``within_s`` old."""
    rows = db.query(
        "SELECT * FROM workers WHERE stopped_at IS NULL AND heartbeat_at >= ? ORDER BY started_at",
        (time.time() - within_s,),
    )
    return [cast(WorkerRow, row) for row in rows]
