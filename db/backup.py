"""``geoloc backup``: a consistent copy of a deployment's database and stored files, taken while it runs.

A backup is a folder::

    manifest.json             format and schema version, creation time, every file with its size and sha256
    database/geoloc.sqlite3   embedded profile: SQLite's online backup of the live database
    database/geoloc.pgdump    distributed profile: ``pg_dump --format=custom`` of the live database
    store/<key>               the file store's maps, photos and query photos (``maps/``, ``images/``, ``queries/``)
    data/<path>               anything else the data folder holds that is not rebuildable

Left out, by decision: ``tmp/`` (uploads still being received: their rows are not committed) and ``cache/``
(the built models and the workers' loaded maps: ``geoloc models build`` and the first job rebuild them), and
the SQLite file's ``-wal``/``-shm``/``-journal`` companions (the online backup already holds their content).

Consistency while the service runs: stored files are copied once before the database snapshot and once after
it (only keys not copied yet). A file is put under its key before the transaction that records its row
commits (:mod:`db.files`), so every row of the snapshot has its file copied, unless that file was both put
after the first pass and deleted before the second; such files are listed in the manifest's
``missing_files`` (and printed) rather than failing the backup. Files written after the snapshot are copied
too and are harmless: the store's orphan sweep deletes files no row refers to. ``manifest.json`` is
written last: a folder without it is an unfinished backup, and :mod:`db.restore` refuses it.
"""

from __future__ import annotations

import datetime
import glob
import hashlib
import json
import os
import shutil
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from db.connection import DATABASE_FILENAME, Database, connect
from db.files import STORED_FOLDERS
from db.migrations import schema_version
from db.stats import stored_file_paths

FORMAT = "geoloc-backup"
FORMAT_VERSION = 1
"""Version of the backup folder's layout and manifest; :mod:`db.restore` reads versions up to this one."""
MANIFEST = "manifest.json"
SQLITE_DUMP = "database/geoloc.sqlite3"
POSTGRES_DUMP = "database/geoloc.pgdump"
SKIPPED_IN_DATA_DIR = ("tmp", "cache")
"""Top-level folders of the data folder a backup leaves out (uploads in progress, rebuildable caches)."""
SQLITE_COMPANIONS = ("", "-wal", "-shm", "-journal")
"""Suffixes of the embedded database's files in the data folder (the file itself and its journals)."""
CHUNK = 1 << 20


class BackupError(Exception):
    """A backup or restore that cannot be done; the message says why (no stack trace for the user)."""


@dataclass(frozen=True)
class Deployment:
    """Where a deployment keeps its data: the data folder, the database, the file store."""

    data_dir: Path
    database: Path | str
    """The SQLite file, or a PostgreSQL URL (the distributed profile)."""
    store_dir: Path

    @property
    def distributed(self) -> bool:
        """Whether the database is PostgreSQL."""
        return isinstance(self.database, str)


@dataclass
class BackupReport:
    """What :func:`create_backup` wrote: the manifest's content."""

    manifest: dict[str, Any]
    missing_files: list[str] = field(default_factory=list)


def postgres_program(name: str) -> str:
    """Path of a PostgreSQL client program (``pg_dump``, ``pg_restore``).

    On PATH, else the newest under ``/usr/lib/postgresql/*/bin`` (Debian's layout, as :mod:`testbed.servers`
    finds the server's).
    """
    found = shutil.which(name) or next(iter(sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"), reverse=True)), None)
    if found is None:
        raise BackupError(f"{name} not found: install the PostgreSQL client programs (Debian: postgresql-client)")
    return found


def libpq_url(url: str) -> str:
    """A database URL as libpq's programs accept it (SQLAlchemy's ``postgresql+psycopg://`` spelled plainly)."""
    return "postgresql://" + url.split("://", 1)[1]


def copy_hashed(source: Path, target: Path) -> tuple[int, str]:
    """Copy ``source`` to ``target`` (folders created); returns (size in bytes, sha256 hex) of what was copied."""
    target.parent.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha256()
    size = 0
    with source.open("rb") as src, target.open("wb") as dst:
        while chunk := src.read(CHUNK):
            digest.update(chunk)
            dst.write(chunk)
            size += len(chunk)
    shutil.copystat(source, target)
    return size, digest.hexdigest()


def file_digest(path: Path) -> tuple[int, str]:
    """(size in bytes, sha256 hex) of a file."""
    digest = hashlib.sha256()
    size = 0
    with path.open("rb") as f:
        while chunk := f.read(CHUNK):
            digest.update(chunk)
            size += len(chunk)
    return size, digest.hexdigest()


def stored_files(deployment: Deployment) -> Iterator[tuple[str, Path]]:
    """(backup path, live file) of every file a backup copies besides the database: store keys, then data files."""
    for folder in STORED_FOLDERS:
        base = deployment.store_dir / folder
        if base.is_dir():
            for path in sorted(base.rglob("*")):
                if path.is_file():
                    yield "store/" + path.relative_to(deployment.store_dir).as_posix(), path
    yield from _data_files(deployment)


def _data_files(deployment: Deployment) -> Iterator[tuple[str, Path]]:
    """Files of the data folder that are neither the database, the store, uploads in progress nor caches."""
    root = deployment.data_dir
    if not root.is_dir():
        return
    skipped = {*SKIPPED_IN_DATA_DIR, *(DATABASE_FILENAME + suffix for suffix in SQLITE_COMPANIONS)}
    store = {(deployment.store_dir / folder).resolve() for folder in STORED_FOLDERS}
    for path in sorted(root.rglob("*")):
        relative = path.relative_to(root)
        if relative.parts[0] in skipped or not path.is_file() or path.is_symlink():
            continue
        if store.intersection(path.resolve().parents):  # the store inside the data folder: copied as store/
            continue
        yield "data/" + relative.as_posix(), path


def _copy_pass(deployment: Deployment, dest: Path, files: dict[str, dict[str, Any]]) -> None:
    """Copy every file not copied yet into ``dest``; a file that vanishes while being read is skipped."""
    for name, path in stored_files(deployment):
        if name in files:
            continue
        try:
            size, sha256 = copy_hashed(path, dest / name)
        except FileNotFoundError:  # deleted since it was listed
            (dest / name).unlink(missing_ok=True)
            continue
        files[name] = {"path": name, "size": size, "sha256": sha256}


def _snapshot_sqlite(database: Path, target: Path) -> tuple[int, set[str]]:
    """SQLite's online backup of ``database`` into ``target``; the snapshot's schema version and stored keys.

    One step: a consistent snapshot, writers not blocked in WAL mode.
    """
    if not database.is_file():
        raise BackupError(f"no database to back up at {database}")
    target.parent.mkdir(parents=True, exist_ok=True)
    source = sqlite3.connect(str(database), timeout=30)
    copy = sqlite3.connect(str(target))
    try:
        source.backup(copy)
        copy.execute("PRAGMA journal_mode = DELETE")
        return int(copy.execute("PRAGMA user_version").fetchone()[0]), stored_file_paths(Database(copy, "sqlite"))
    finally:
        copy.close()
        source.close()


def _snapshot_postgres(url: str, target: Path) -> tuple[int, set[str]]:
    """``pg_dump --format=custom`` of the live database into ``target`` (a consistent snapshot).

    Returns the schema version and the stored keys rows refer to, both read just before the dump.
    """
    target.parent.mkdir(parents=True, exist_ok=True)
    db = connect(url)
    try:
        version, referenced = schema_version(db), stored_file_paths(db)
    finally:
        db.close()
    argv = [postgres_program("pg_dump"), "--format=custom", "--no-owner", "--no-privileges", "--file", str(target)]
    done = subprocess.run([*argv, "--dbname", libpq_url(url)], check=False, capture_output=True, text=True)
    if done.returncode != 0:
        raise BackupError(f"pg_dump failed: {done.stderr.strip()}")
    return version, referenced


def create_backup(deployment: Deployment, dest: Path, *, now: float | None = None) -> BackupReport:
    """Back up ``deployment`` into the new folder ``dest`` (absent or empty), while the service may run.

    Returns the report whose manifest was written to ``dest/manifest.json``; raises :class:`BackupError`
    with the reason when it cannot (``dest`` not empty, no database, ``pg_dump`` failing).
    """
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
        raise BackupError(f"{dest} exists and is not an empty folder: a backup goes to a new folder")
    if not deployment.distributed and not Path(deployment.database).is_file():
        raise BackupError(f"no database to back up at {deployment.database}")
    dest.mkdir(parents=True, exist_ok=True)
    files: dict[str, dict[str, Any]] = {}
    _copy_pass(deployment, dest, files)
    if deployment.distributed:
        dump = POSTGRES_DUMP
        version, referenced = _snapshot_postgres(str(deployment.database), dest / dump)
    else:
        dump = SQLITE_DUMP
        version, referenced = _snapshot_sqlite(Path(deployment.database), dest / dump)
    _copy_pass(deployment, dest, files)
    size, sha256 = file_digest(dest / dump)
    files[dump] = {"path": dump, "size": size, "sha256": sha256}
    missing = sorted(key for key in referenced if f"store/{key}" not in files)
    created = time.time() if now is None else now
    manifest = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "schema_version": version,
        "profile": "distributed" if deployment.distributed else "embedded",
        "created_at": datetime.datetime.fromtimestamp(created, datetime.UTC).isoformat().replace("+00:00", "Z"),
        "database": dump,
        "missing_files": missing,
        "files": sorted(files.values(), key=lambda entry: str(entry["path"])),
    }
    partial = dest / (MANIFEST + ".partial")
    partial.write_text(json.dumps(manifest, indent=1) + "\n")
    os.replace(partial, dest / MANIFEST)
    return BackupReport(manifest, missing)
