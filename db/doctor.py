"""The deployment's consistency checks and their safe repairs (``geoloc doctor``).

What a crash can leave behind, and what :func:`examine` finds (each a :class:`Finding`, by its ``check``):

- ``integrity``: SQLite's ``PRAGMA integrity_check`` and ``foreign_key_check`` (PostgreSQL keeps its own pages
  consistent; it is not checked here). Never repaired: restore a backup.
- ``orphaned_file``: a stored file (``maps/``, ``images/``, ``queries/``) that no row names, left by a crash between
  putting the file in place and the commit, or between a delete's commit and the file's removal. Repair: the file
  is deleted (no row refers to it, so no data goes with it).
- ``temp_file``: an upload that was being received when its API process died (``tmp/upload-*.part``). Repair:
  deleted.
- ``missing_file``: a map, reference or query row, not yet ``failed``, whose stored file is gone. Repair (a
  decision): the row is kept and marked ``failed`` with the reason (``the stored file KEY is missing``), and its
  job, if not finished, is failed with it. Deleting the row instead would also drop what was computed from the
  file (labels, index entries, answers) without anyone seeing why; a failed row is shown by the API with its
  reason, and ``DELETE`` then an upload of the photo again restores it.
- ``dead_worker``: a worker registered as running whose process is gone: not running on this host, or no
  heartbeat for ``stale_s``. Repair: marked stopped.
- ``stuck_job``: a ``running`` job whose worker is gone (as above, or stopped) or whose lease expired. Repair: back
  to ``queued`` (the attempt counts, as when another worker takes over an expired lease), or ``failed`` with the
  reason ``worker lost`` when its attempts are used up. The running service does the same by itself once the lease
  expires; the doctor does it at once.
- ``unfinished_work``: a reference, lone query, track or map still ``queued``/``processing`` whose job is gone
  or ``done``: nothing would ever finish it. Repair: marked ``failed`` with the reason.

Stored and temporary files younger than ``grace_s`` are not judged: an upload puts its file in place just before
its row commits. With the service stopped, a grace of 0 judges every file. Every repair re-checks its finding
inside a transaction first (a row deleted, a job finished meanwhile is left alone) and is reported; no row is
deleted.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from db.connection import Database, connect, is_postgres_url, transaction
from db.doctor_checks import (
    MissingFile,
    StuckJob,
    UnfinishedRow,
    dead_workers,
    integrity_problems,
    orphaned_files,
    rows_missing_files,
    stale_temp_files,
    stuck_jobs,
    unfinished_work,
)
from db.files import FileStore, open_store
from db.jobs import stop_worker
from db.migrations import LATEST_VERSION, schema_version
from db.queries import QUERY_PHOTOS_LOCK
from db.stats import stored_file_paths

Check = Literal[
    "integrity", "orphaned_file", "temp_file", "missing_file", "dead_worker", "stuck_job", "unfinished_work"
]
CHECKS: tuple[Check, ...] = (
    "integrity",
    "orphaned_file",
    "temp_file",
    "missing_file",
    "dead_worker",
    "stuck_job",
    "unfinished_work",
)
DEFAULT_GRACE_S = 300.0
"""Stored and temporary files younger than this (s) are not judged (an upload may be between file and row)."""


class DoctorError(Exception):
    """The deployment cannot be examined (no database, a schema this code does not know); the message says why."""


@dataclass(frozen=True)
class Finding:
    """One problem: which check found it, what it concerns (a file key, ``job 7``), what is wrong, what was done.

    ``repair`` is None while it is not repaired (a report without ``--repair``, or one that cannot be repaired).
    """

    check: Check
    subject: str
    problem: str
    repair: str | None = None

    def to_json(self) -> dict[str, str | None]:
        """The finding as a JSON object."""
        return {"check": self.check, "subject": self.subject, "problem": self.problem, "repair": self.repair}


@dataclass
class DoctorReport:
    """What :func:`examine` found and repaired.

    ``integrity`` is SQLite's answer (``ok``) or None on PostgreSQL (not checked); ``checked`` counts what was
    looked at (stored files, rows with files, running jobs, registered workers).
    """

    profile: Literal["embedded", "distributed"]
    integrity: str | None
    repair: bool
    checked: dict[str, int] = field(default_factory=dict)
    findings: list[Finding] = field(default_factory=list)

    @property
    def problems(self) -> list[Finding]:
        """The findings not repaired."""
        return [finding for finding in self.findings if finding.repair is None]

    @property
    def clean(self) -> bool:
        """Whether nothing is left to repair."""
        return not self.problems

    def counts(self) -> dict[str, int]:
        """Findings per check (every check named, 0 included)."""
        return {check: sum(finding.check == check for finding in self.findings) for check in CHECKS}

    def to_json(self) -> dict[str, Any]:
        """The report as a JSON object (``geoloc doctor --json``)."""
        return {
            "profile": self.profile,
            "integrity": self.integrity,
            "repair": self.repair,
            "clean": self.clean,
            "checked": dict(self.checked),
            "counts": self.counts(),
            "problems": len(self.problems),
            "repaired": len(self.findings) - len(self.problems),
            "findings": [finding.to_json() for finding in self.findings],
        }


# --- repairs (each re-checks its finding in a transaction; returns what it did, None when nothing was left to do) ---


def remove_orphaned_files(db: Database, store: FileStore, keys: list[str]) -> list[str]:
    """Delete those of ``keys`` that no row names now; returns the deleted keys.

    Checked and deleted in one transaction under the query-photo lock: on SQLite that is the one write lock
    every upload takes before it puts its file in place, so no upload can slip in between.
    """
    with transaction(db):
        db.lock(QUERY_PHOTOS_LOCK)
        referenced = stored_file_paths(db)
        gone = [key for key in keys if key not in referenced]
        store.delete(*gone)
    return gone


def _fail_job(db: Database, job_id: int, reason: str, now: float) -> bool:
    """Fail job ``job_id`` with ``reason`` if it is not finished (its worker's outcome, if any, is then dropped)."""
    cursor = db.execute(
        "UPDATE jobs SET status = 'failed', error = ?, finished_at = ?, updated_at = ?, lease_owner = NULL,"
        " lease_expires_at = NULL WHERE id = ? AND status IN ('queued', 'running')",
        (reason, now, now, job_id),
    )
    return cursor.rowcount == 1


def _fail_row(db: Database, table: str, row_id: int, reason: str, now: float, where: str, code: str) -> bool:
    """Mark a map, reference, query or track ``failed`` with ``reason`` (a map also with the error code ``code``)."""
    if table == "maps":
        sql = "UPDATE maps SET status = 'failed', error = ?, error_code = ? WHERE id = ?"
        params: tuple[Any, ...] = (reason, code, row_id)
    else:
        sql = f"UPDATE {table} SET status = 'failed', error = ?, updated_at = ? WHERE id = ?"
        params = (reason, now, row_id)
    return db.execute(sql + where, params).rowcount == 1


def fail_row_missing_file(db: Database, store: FileStore, row: MissingFile, *, now: float) -> str | None:
    """Mark a row whose file is gone ``failed`` with the reason, and its unfinished job (not a track's) with it."""
    reason = f"the stored file {row.key} is missing (found by geoloc doctor)"
    with transaction(db):
        if store.local_path(row.key).is_file():
            return None  # put back meanwhile
        if not _fail_row(db, row.table, row.row_id, reason, now, " AND status != 'failed'", "stored_file_missing"):
            return None  # deleted or failed meanwhile
        job = row.job_id is not None and not row.frame and _fail_job(db, row.job_id, reason, now)
    return f"marked failed: {reason}" + (f"; its job {row.job_id} failed with it" if job else "")


def mark_worker_stopped(db: Database, worker_id: str) -> str:
    """Record a dead worker as stopped (it no longer counts as live or stale)."""
    stop_worker(db, worker_id)
    return "marked stopped"


def requeue_or_fail(db: Database, job: StuckJob, *, now: float) -> str | None:
    """Give a stuck job back to the queue, or fail it when its attempts are used up; what was done, or None.

    The update holds only while the job still runs under the same lease owner (a worker that took it over meanwhile
    keeps it). The attempt that was cut off counts, as when a worker takes over an expired lease.
    """
    owner = "lease_owner IS NULL" if job.lease_owner is None else "lease_owner = ?"
    owner_params: tuple[Any, ...] = () if job.lease_owner is None else (job.lease_owner,)
    lost = f"worker lost: {job.why} during attempt {job.attempts} of {job.max_attempts}"
    if job.attempts >= job.max_attempts:
        outcome, reason = "failed", f"{lost} (failed by geoloc doctor)"
        sets = "status = 'failed', finished_at = ?, run_after = run_after"
    else:
        outcome, reason = "queued", f"{lost} (queued again by geoloc doctor)"
        sets = "status = 'queued', finished_at = NULL, run_after = ?"
    cursor = db.execute(
        f"UPDATE jobs SET {sets}, updated_at = ?, lease_owner = NULL, lease_expires_at = NULL,"
        " error = COALESCE(error || ?, '') || ?"
        f" WHERE id = ? AND status = 'running' AND {owner}",
        (now, now, "\n", reason, job.job_id, *owner_params),
    )
    return f"{outcome}: {reason}" if cursor.rowcount == 1 else None


def fail_unfinished(db: Database, row: UnfinishedRow, *, now: float) -> str | None:
    """Mark a pending row whose job is gone or done ``failed`` with the reason; what was done, or None."""
    reason = f"nothing would finish it: {row.why} without an outcome for it (failed by geoloc doctor)"
    with transaction(db):
        if _fail_row(db, row.table, row.row_id, reason, now, " AND status IN ('queued', 'processing')", "unfinished"):
            return f"marked failed: {reason}"
    return None


# --- the whole examination ----------------------------------------------------------------------------------


def examine(
    db: Database,
    store: FileStore,
    *,
    repair: bool = False,
    grace_s: float = DEFAULT_GRACE_S,
    lease_s: float = 60.0,
    now: float | None = None,
) -> DoctorReport:
    """Run every check (module docstring) and, with ``repair``, every safe repair; the report of both.

    grace_s: files younger than this (s) are not judged. lease_s: the job lease (``GEOLOC_JOB_LEASE_S``); a worker
    with no heartbeat for three leases (at least 60 s) counts as gone.
    """
    now = time.time() if now is None else now
    stale_s = max(3 * lease_s, 60.0)
    integrity = integrity_problems(db)
    report = DoctorReport(
        "distributed" if db.is_postgres else "embedded",
        None if db.is_postgres else ("ok" if not integrity else "; ".join(integrity[:5])),
        repair,
    )
    report.findings += [Finding("integrity", "database", problem) for problem in integrity]

    orphans = orphaned_files(db, store, grace_s)
    removed = set(remove_orphaned_files(db, store, orphans)) if repair and orphans else set()
    report.findings += [
        Finding("orphaned_file", key, "no row names this stored file", "deleted" if key in removed else None)
        for key in orphans
    ]
    for path in stale_temp_files(store, grace_s):
        done = None
        if repair:
            path.unlink(missing_ok=True)
            done = "deleted"
        report.findings.append(Finding("temp_file", f"tmp/{path.name}", "an upload cut off while received", done))

    missing, with_files = rows_missing_files(db, store)
    for row in missing:
        done = fail_row_missing_file(db, store, row, now=now) if repair else None
        report.findings.append(Finding("missing_file", row.subject, f"its stored file {row.key} is missing", done))

    dead = dead_workers(db, now=now, stale_s=stale_s)
    for worker_id, why in dead:
        done = mark_worker_stopped(db, worker_id) if repair else None
        report.findings.append(Finding("dead_worker", f"worker {worker_id}", f"registered as running, {why}", done))

    stuck, running = stuck_jobs(db, now=now, gone_workers={worker_id for worker_id, _ in dead}, stale_s=stale_s)
    for job in stuck:
        done = requeue_or_fail(db, job, now=now) if repair else None
        report.findings.append(Finding("stuck_job", f"job {job.job_id} ({job.kind})", f"running, but {job.why}", done))

    for pending in unfinished_work(db):
        done = fail_unfinished(db, pending, now=now) if repair else None
        report.findings.append(Finding("unfinished_work", pending.subject, f"still pending, but {pending.why}", done))

    report.checked = {
        "stored_files": sum(1 for _ in store.stored_keys(0.0)),
        "rows_with_files": with_files,
        "running_jobs": running,
        "workers": int(db.execute("SELECT COUNT(*) FROM workers WHERE stopped_at IS NULL").fetchone()[0]),
    }
    return report


def examine_deployment(
    database: Path | str,
    store_root: Path,
    *,
    repair: bool = False,
    grace_s: float = DEFAULT_GRACE_S,
    lease_s: float = 60.0,
) -> DoctorReport:
    """:func:`examine` on the deployment at ``database`` (a SQLite file or a PostgreSQL URL) and ``store_root``.

    Raises :class:`DoctorError` when there is no database there or its schema is not this code's (the service
    migrates it when it starts).
    """
    if not is_postgres_url(database) and not Path(database).is_file():
        raise DoctorError(f"no database at {database}: check GEOLOC_DATA_DIR")
    try:
        db = connect(database)
    except Exception as exc:  # psycopg's OperationalError, sqlite3's: the message is what the user needs
        raise DoctorError(f"cannot open the database: {exc}") from exc
    try:
        version = schema_version(db)
        if version != LATEST_VERSION:
            raise DoctorError(
                f"the database is at schema version {version}, this geoloc's is {LATEST_VERSION}: "
                + ("start the service once to migrate it" if version < LATEST_VERSION else "use a newer geoloc")
            )
        return examine(db, open_store(store_root), repair=repair, grace_s=grace_s, lease_s=lease_s)
    finally:
        db.close()
