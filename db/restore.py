"""``geoloc restore``: a backup folder (:mod:`db.backup`) back into a deployment's data folder, database and store.

Checked before anything is written, in this order, each refusal naming what is wrong:

1. ``manifest.json`` is there and of a known format version (a folder without it is an unfinished backup);
2. the backup's schema version is not newer than this code's (:data:`db.migrations.LATEST_VERSION`): a
   newer backup needs a newer ``geoloc``; an older one is restored as it is and migrated forward when the
   service next starts;
3. the backup's profile (embedded, distributed) is the target's;
4. every file of the manifest is there with its size and sha256, and every path stays inside the backup;
5. the target holds no data (no database rows, no stored file, no other file of the data folder but
   ``cache/``), unless ``force``, which first deletes what it holds (``cache/`` is left alone: rebuildable).

The service must not run on the target while it is restored (stop it; start it after).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path, PurePosixPath
from typing import Any

from db.backup import (
    FORMAT,
    FORMAT_VERSION,
    MANIFEST,
    SQLITE_COMPANIONS,
    BackupError,
    Deployment,
    copy_hashed,
    file_digest,
    libpq_url,
    postgres_program,
    stored_files,
)
from db.connection import connect
from db.files import STORED_FOLDERS
from db.migrations import LATEST_VERSION, schema_version
from db.stats import table_counts


def read_manifest(src: Path) -> dict[str, Any]:
    """The backup's manifest, checked for format, format version and schema version (else :class:`BackupError`)."""
    path = src / MANIFEST
    if not path.is_file():
        raise BackupError(f"{src} is not a complete geoloc backup: it has no {MANIFEST}")
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BackupError(f"{path} is not a readable manifest: {exc}") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise BackupError(f"{path} is not a geoloc backup manifest")
    version = manifest.get("format_version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise BackupError(f"backup format version {version} is not one this geoloc reads (up to {FORMAT_VERSION})")
    schema = manifest.get("schema_version")
    if not isinstance(schema, int) or schema > LATEST_VERSION:
        raise BackupError(
            f"the backup's schema version {schema} is newer than this geoloc's ({LATEST_VERSION}): "
            "restore it with the geoloc release that made it, or a newer one"
        )
    return manifest


def _safe_path(name: object) -> str:
    """A manifest path, refused unless relative, inside the backup and under ``database/``, ``store/`` or ``data/``."""
    path = PurePosixPath(str(name))
    if path.is_absolute() or ".." in path.parts or not path.parts or path.parts[0] not in ("database", "store", "data"):
        raise BackupError(f"the manifest lists a file outside the backup's folders: {name!r}")
    return path.as_posix()


def verify_backup(src: Path) -> dict[str, Any]:
    """Check the manifest and every file's size and sha256; returns the manifest (refusals name the bad file)."""
    manifest = read_manifest(src)
    for entry in manifest.get("files", []):
        name = _safe_path(entry.get("path"))
        path = src / name
        if not path.is_file():
            raise BackupError(f"the backup is incomplete: {name} is missing")
        size, sha256 = file_digest(path)
        if size != entry.get("size") or sha256 != entry.get("sha256"):
            raise BackupError(f"the backup is corrupt: {name} does not match its checksum in {MANIFEST}")
    database = manifest.get("database")
    if not any(entry.get("path") == database for entry in manifest.get("files", [])):
        raise BackupError(f"the manifest lists no database file ({database!r})")
    return manifest


def held_data(deployment: Deployment) -> list[str]:
    """What the target already holds (empty when a restore may write there): a few names, for the refusal."""
    held: list[str] = []
    if deployment.distributed or Path(deployment.database).is_file():
        db = connect(deployment.database)
        try:
            if schema_version(db) > 0:  # a migrated database without rows (a service started there) holds nothing
                held += [f"{n} {table} rows" for table, n in table_counts(db).items() if n]
        finally:
            db.close()
    held += [name for name, _ in stored_files(deployment)]
    return held


def _sqlite_files(database: Path) -> list[Path]:
    return [database.with_name(database.name + suffix) for suffix in SQLITE_COMPANIONS]


def _clear(deployment: Deployment) -> None:
    """Delete what a forced restore replaces: the database (tables or file), stored files, other data files."""
    if deployment.distributed:
        db = connect(deployment.database)
        try:
            rows = db.execute("SELECT tablename FROM pg_tables WHERE schemaname = current_schema()").fetchall()
            tables = [row[0] for row in rows]
            if tables:
                db.execute("DROP TABLE IF EXISTS " + ", ".join(f'"{name}"' for name in tables) + " CASCADE")
        finally:
            db.close()
    else:
        for path in _sqlite_files(Path(deployment.database)):
            path.unlink(missing_ok=True)
    for _, path in list(stored_files(deployment)):
        path.unlink(missing_ok=True)
    for folder in (*STORED_FOLDERS, "tmp"):
        shutil.rmtree(deployment.store_dir / folder, ignore_errors=True)


def _restore_postgres(url: str, dump: Path) -> None:
    """``pg_restore`` the dump into the (cleared) database, in one transaction."""
    argv = [postgres_program("pg_restore"), "--no-owner", "--no-privileges", "--single-transaction", "--exit-on-error"]
    done = subprocess.run([*argv, "--dbname", libpq_url(url), str(dump)], check=False, capture_output=True, text=True)
    if done.returncode != 0:
        raise BackupError(f"pg_restore failed: {done.stderr.strip()}")


def restore_backup(deployment: Deployment, src: Path, *, force: bool = False) -> dict[str, Any]:
    """Restore the backup folder ``src`` into ``deployment``; returns its manifest.

    Raises :class:`BackupError` (nothing written) when a check of the module docstring fails.
    """
    manifest = verify_backup(src)
    profile = "distributed" if deployment.distributed else "embedded"
    if manifest.get("profile") != profile:
        raise BackupError(f"the backup is of the {manifest.get('profile')} profile; the target is {profile}")
    held = held_data(deployment)
    if held and not force:
        shown = ", ".join(held[:5]) + (f" and {len(held) - 5} more" if len(held) > 5 else "")
        raise BackupError(f"the target already holds data ({shown}); pass --force to replace it")
    _clear(deployment)
    deployment.data_dir.mkdir(parents=True, exist_ok=True)
    dump = src / manifest["database"]
    if deployment.distributed:
        _restore_postgres(str(deployment.database), dump)
    else:
        database = Path(deployment.database)
        partial = database.with_name(database.name + ".restoring")
        copy_hashed(dump, partial)
        os.replace(partial, database)
    for entry in manifest["files"]:
        name = _safe_path(entry["path"])
        head, _, rest = name.partition("/")
        if head == "store":
            copy_hashed(src / name, deployment.store_dir / rest)
        elif head == "data":
            copy_hashed(src / name, deployment.data_dir / rest)
    return manifest
