"""The checks of :mod:`db.doctor`: what a crash can leave inconsistent, found without changing anything.

Each returns what it found, typed; :func:`db.doctor.examine` turns them into findings and repairs them.
"""

from __future__ import annotations

import contextlib
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from db.connection import Database
from db.files import FileStore
from db.stats import stored_file_paths

TEMP_UPLOADS = "upload-*.part"
"""Names of uploads being received in the store's ``tmp/`` (:mod:`service.uploads`)."""
SUBJECTS = {"maps": "map", "reference_images": "reference", "queries": "query", "tracks": "track"}
"""A table's rows as the API names them."""
FILE_COLUMNS = (("maps", "source_path"), ("reference_images", "image_path"), ("queries", "image_path"))
"""Where rows name their stored files."""


# --- checks -----------------------------------------------------------------------------------------------


def integrity_problems(db: Database) -> list[str]:
    """SQLite's ``integrity_check`` messages (none: ``ok``) and foreign-key violations; [] on PostgreSQL."""
    if db.is_postgres:
        return []
    messages = [str(row[0]) for row in db.execute("PRAGMA integrity_check").fetchall()]
    problems = [message for message in messages if message != "ok"]
    for table, rowid, parent, _ in db.execute("PRAGMA foreign_key_check").fetchall():
        problems.append(f"row {rowid} of {table} refers to a missing row of {parent}")
    return problems


def orphaned_files(db: Database, store: FileStore, grace_s: float) -> list[str]:
    """Stored keys older than ``grace_s`` (s) that no row names, sorted.

    The files are listed before the rows are read: a file whose row commits in between is then named.
    """
    keys = sorted(store.stored_keys(grace_s))
    referenced = stored_file_paths(db)
    return [key for key in keys if key not in referenced]


def stale_temp_files(store: FileStore, grace_s: float) -> list[Path]:
    """Temporary uploads (``tmp/upload-*.part``) last written more than ``grace_s`` (s) ago, sorted."""
    cutoff = time.time() - grace_s
    found = []
    for path in store.local_path("tmp").glob(TEMP_UPLOADS):  # not temp_dir(): a report creates no folder
        with contextlib.suppress(OSError):
            if path.stat().st_mtime < cutoff:
                found.append(path)
    return sorted(found)


@dataclass(frozen=True)
class MissingFile:
    """A row (``table``, ``row_id``) whose stored file ``key`` is gone; ``job_id`` its job, ``frame`` a track's."""

    table: str
    row_id: int
    key: str
    job_id: int | None
    frame: bool = False

    @property
    def subject(self) -> str:
        """``reference 3``, ``query 9``, ``map 1``."""
        return f"{SUBJECTS[self.table]} {self.row_id}"


def rows_missing_files(db: Database, store: FileStore) -> tuple[list[MissingFile], int]:
    """Map, reference and query rows not yet ``failed`` whose stored file is gone; and how many rows were looked at."""
    missing: list[MissingFile] = []
    looked = 0
    for table, column in FILE_COLUMNS:
        frame = ", track_id" if table == "queries" else ", NULL"
        rows = db.execute(
            f"SELECT id, {column}, job_id{frame} FROM {table} WHERE {column} IS NOT NULL AND status != 'failed'"
        ).fetchall()
        looked += len(rows)
        for row_id, key, job_id, track_id in rows:
            if not store.local_path(key).is_file():
                missing.append(MissingFile(table, int(row_id), str(key), job_id, track_id is not None))
    return missing, looked


def process_running(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (a zombie does not)."""
    with contextlib.suppress(OSError):
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return not Path("/proc/self").exists()  # /proc is there, the process's entry is not: it is gone


def dead_workers(db: Database, *, now: float, stale_s: float, host: str | None = None) -> list[tuple[str, str]]:
    """Workers not stopped whose process is gone: (worker id, why), by id.

    Gone: on this ``host`` (default this machine's name) its pid does not run; anywhere, no heartbeat for
    ``stale_s`` (s).
    """
    host = host or socket.gethostname()
    rows = db.execute(
        "SELECT worker_id, pid, hostname, heartbeat_at FROM workers WHERE stopped_at IS NULL ORDER BY worker_id"
    ).fetchall()
    dead = []
    for worker_id, pid, hostname, heartbeat_at in rows:
        if hostname == host and not process_running(int(pid)):
            dead.append((str(worker_id), f"its process {pid} is not running"))
        elif heartbeat_at < now - stale_s:
            dead.append((str(worker_id), f"no heartbeat for {now - heartbeat_at:.0f} s"))
    return dead


@dataclass(frozen=True)
class StuckJob:
    """A running job nobody runs: its id, kind, attempts, the lease owner and why it is stuck."""

    job_id: int
    kind: str
    attempts: int
    max_attempts: int
    lease_owner: str | None
    why: str


def stuck_jobs(db: Database, *, now: float, gone_workers: set[str], stale_s: float) -> tuple[list[StuckJob], int]:
    """Running jobs nobody runs, and how many jobs run.

    Nobody: its worker is gone (in ``gone_workers``, or stopped), its lease expired, or no heartbeat for ``stale_s``.
    """
    rows = db.execute(
        "SELECT j.id, j.kind, j.attempts, j.max_attempts, j.lease_owner, j.lease_expires_at, j.heartbeat_at,"
        " w.stopped_at FROM jobs j LEFT JOIN workers w ON w.worker_id = j.lease_owner"
        " WHERE j.status = 'running' ORDER BY j.id"
    ).fetchall()
    stuck = []
    for job_id, kind, attempts, max_attempts, owner, expires_at, heartbeat_at, stopped_at in rows:
        if owner is None:
            why = "it has no lease owner"
        elif owner in gone_workers:
            why = f"its worker {owner} is gone"
        elif stopped_at is not None:
            why = f"its worker {owner} stopped"
        elif expires_at is None or expires_at < now:
            why = f"its lease expired {now - (expires_at or now):.0f} s ago"
        elif heartbeat_at is None or heartbeat_at < now - stale_s:
            why = "its worker has not renewed its lease"
        else:
            continue
        stuck.append(StuckJob(int(job_id), str(kind), int(attempts), int(max_attempts), owner, why))
    return stuck, len(rows)


@dataclass(frozen=True)
class UnfinishedRow:
    """A row still queued or processing that nothing will finish: its job is gone (``job_status`` None) or done."""

    table: str
    row_id: int
    job_id: int | None
    job_status: str | None

    @property
    def subject(self) -> str:
        """``reference 3``, ``track 2``."""
        return f"{SUBJECTS[self.table]} {self.row_id}"

    @property
    def why(self) -> str:
        """Why nothing will finish it."""
        return "it has no job" if self.job_id is None else f"its job {self.job_id} is {self.job_status or 'gone'}"


def unfinished_work(db: Database) -> list[UnfinishedRow]:
    """References, lone queries (not a track's frames), tracks and maps still pending whose job is gone or done."""
    found = []
    for table in ("maps", "reference_images", "queries", "tracks"):
        lone = " AND r.track_id IS NULL" if table == "queries" else ""
        rows = db.execute(
            f"SELECT r.id, r.job_id, j.status FROM {table} r LEFT JOIN jobs j ON j.id = r.job_id"
            f" WHERE r.status IN ('queued', 'processing'){lone} AND (j.id IS NULL OR j.status = 'done') ORDER BY r.id"
        ).fetchall()
        found += [UnfinishedRow(table, int(row_id), job_id, status) for row_id, job_id, status in rows]
    return found
