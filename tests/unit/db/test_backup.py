"""Backup and restore (db.backup, db.restore, ``geoloc backup|restore``) on real SQLite files and a real PostgreSQL.

The service end to end, backed up while it runs: ``tests/e2e/test_backup.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from contracts.jobs import JobPayload
from db import LATEST_VERSION, connect, migrate
from db import jobs as job_store
from db.backup import MANIFEST, BackupError, Deployment, create_backup
from db.restore import restore_backup
from db.stats import table_counts
from testbed.servers import PostgresServer


class AnyPayload(JobPayload):
    """A job payload with one field."""

    x: int = 0


def _deployment(root: Path, database: Path | str | None = None) -> Deployment:
    data = root / "data"
    return Deployment(data, database or data / "geoloc.sqlite3", data)


def _filled(root: Path, database: str | None = None) -> Deployment:
    """A migrated database with two jobs, stored files, a data file, and what a backup leaves out (cache, tmp).

    ``database``: a PostgreSQL URL, else a SQLite file in the data folder.
    """
    deployment = _deployment(root, database)
    deployment.data_dir.mkdir(parents=True)
    db = connect(deployment.database)
    try:
        migrate(db)
        for x in (1, 2):
            job_store.enqueue_job(db, "k", AnyPayload(x=x))
    finally:
        db.close()
    for name, text in {
        "images/1/abc.jpg": "photo",
        "maps/def.geojson": "{}",
        "queries/9/q.jpg": "query",
        "notes/site.txt": "kept",
        "cache/models/m.onnx": "rebuildable",
        "tmp/upload-1": "half",
    }.items():
        (deployment.data_dir / name).parent.mkdir(parents=True, exist_ok=True)
        (deployment.data_dir / name).write_text(text)
    return deployment


def _jobs(deployment: Deployment) -> list[str]:
    db = connect(deployment.database)
    try:
        return [row["payload"] for row in db.query("SELECT payload FROM jobs ORDER BY id")]
    finally:
        db.close()


def test_a_backup_holds_the_database_and_stored_files_but_no_cache_or_uploads(tmp_path: Path) -> None:
    deployment = _filled(tmp_path)
    report = create_backup(deployment, tmp_path / "backup")
    manifest = json.loads((tmp_path / "backup" / MANIFEST).read_text())
    assert manifest == report.manifest and manifest["schema_version"] == LATEST_VERSION
    assert manifest["format_version"] == 1 and manifest["profile"] == "embedded"
    assert manifest["created_at"].endswith("Z") and manifest["missing_files"] == []
    paths = [entry["path"] for entry in manifest["files"]]
    assert paths == [
        "data/notes/site.txt",
        "database/geoloc.sqlite3",
        "store/images/1/abc.jpg",
        "store/maps/def.geojson",
        "store/queries/9/q.jpg",
    ]
    assert all(len(entry["sha256"]) == 64 and entry["size"] > 0 for entry in manifest["files"])
    with pytest.raises(BackupError, match="not an empty folder"):
        create_backup(deployment, tmp_path / "backup")
    with pytest.raises(BackupError, match="no database to back up at"):
        create_backup(_deployment(tmp_path / "none"), tmp_path / "backup-of-nothing")
    assert not (tmp_path / "backup-of-nothing").exists(), "nothing written"


def test_a_store_inside_the_data_folder_is_copied_once(tmp_path: Path) -> None:
    deployment = _filled(tmp_path)
    (deployment.data_dir / "store" / "images").mkdir(parents=True)
    (deployment.data_dir / "images" / "1" / "abc.jpg").rename(deployment.data_dir / "store" / "images" / "abc.jpg")
    inside = Deployment(deployment.data_dir, deployment.database, deployment.data_dir / "store")
    paths = [entry["path"] for entry in create_backup(inside, tmp_path / "backup").manifest["files"]]
    assert "store/images/abc.jpg" in paths and not any(p.startswith("data/store/") for p in paths)


def test_restore_into_a_fresh_folder_gives_the_same_rows_and_files(tmp_path: Path) -> None:
    source = _filled(tmp_path / "a")
    create_backup(source, tmp_path / "backup")
    target = _deployment(tmp_path / "b")
    restore_backup(target, tmp_path / "backup")
    assert _jobs(target) == _jobs(source)
    for name in ("images/1/abc.jpg", "maps/def.geojson", "queries/9/q.jpg", "notes/site.txt"):
        assert (target.data_dir / name).read_text() == (source.data_dir / name).read_text()
    assert not (target.data_dir / "cache").exists() and not (target.data_dir / "tmp").exists()


def test_a_corrupt_backup_is_refused_naming_the_file_and_nothing_is_written(tmp_path: Path) -> None:
    create_backup(_filled(tmp_path / "a"), tmp_path / "backup")
    (tmp_path / "backup" / "store" / "maps" / "def.geojson").write_text("{ }")
    target = _deployment(tmp_path / "b")
    with pytest.raises(BackupError, match=r"corrupt: store/maps/def\.geojson does not match its checksum"):
        restore_backup(target, tmp_path / "backup")
    assert not target.data_dir.exists()
    (tmp_path / "backup" / "store" / "maps" / "def.geojson").unlink()
    with pytest.raises(BackupError, match=r"incomplete: store/maps/def\.geojson is missing"):
        restore_backup(target, tmp_path / "backup")
    assert not target.data_dir.exists()


def test_an_unfinished_or_newer_backup_is_refused(tmp_path: Path) -> None:
    create_backup(_filled(tmp_path / "a"), tmp_path / "backup")
    manifest_path = tmp_path / "backup" / MANIFEST
    manifest = json.loads(manifest_path.read_text())
    manifest_path.write_text(json.dumps({**manifest, "schema_version": LATEST_VERSION + 1}))
    target = _deployment(tmp_path / "b")
    with pytest.raises(BackupError, match=f"schema version {LATEST_VERSION + 1} is newer than this geoloc's"):
        restore_backup(target, tmp_path / "backup")
    manifest_path.write_text(json.dumps({**manifest, "files": [*manifest["files"], {"path": "../x", "size": 1}]}))
    with pytest.raises(BackupError, match="outside the backup"):
        restore_backup(target, tmp_path / "backup")
    manifest_path.unlink()
    with pytest.raises(BackupError, match="not a complete geoloc backup: it has no manifest.json"):
        restore_backup(target, tmp_path / "backup")
    assert not target.data_dir.exists()


def test_a_target_with_data_is_refused_unless_forced_and_force_replaces_it(tmp_path: Path) -> None:
    source = _filled(tmp_path / "a")
    create_backup(source, tmp_path / "backup")
    target = _filled(tmp_path / "b")
    db = connect(target.database)
    try:
        job_store.enqueue_job(db, "k", AnyPayload(x=3))
    finally:
        db.close()
    (target.data_dir / "images" / "1" / "other.jpg").write_text("other")
    held = r"already holds data \(3 jobs rows, store/maps/def\.geojson, .* and 1 more\); pass --force"
    with pytest.raises(BackupError, match=held):
        restore_backup(target, tmp_path / "backup")
    assert len(_jobs(target)) == 3
    restore_backup(target, tmp_path / "backup", force=True)
    assert _jobs(target) == _jobs(source)
    assert not (target.data_dir / "images" / "1" / "other.jpg").exists()
    assert (target.data_dir / "cache" / "models" / "m.onnx").read_text() == "rebuildable", "the cache is left alone"
    empty = _deployment(tmp_path / "c")  # a service started there once: a migrated database without rows
    empty.data_dir.mkdir(parents=True)
    db = connect(empty.database)
    migrate(db)
    db.close()
    restore_backup(empty, tmp_path / "backup")
    assert _jobs(empty) == _jobs(source)


def test_the_cli_backs_up_and_refuses_a_corrupt_backup_with_the_reason(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = _filled(tmp_path / "a")
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(source.data_dir))
    runner = CliRunner()
    done = runner.invoke(app, ["backup", str(tmp_path / "backup")])
    assert done.exit_code == 0, done.output
    assert "backup of the embedded profile" in done.output and "6 files" not in done.output
    (tmp_path / "backup" / "store" / "images" / "1" / "abc.jpg").write_text("flipped")
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path / "b" / "data"))
    done = runner.invoke(app, ["restore", str(tmp_path / "backup")])
    assert done.exit_code == 2
    assert "error: the backup is corrupt: store/images/1/abc.jpg does not match its checksum" in done.output
    assert "Traceback" not in done.output and not (tmp_path / "b" / "data" / "geoloc.sqlite3").exists()


def test_postgres_backup_and_restore_with_pg_dump(tmp_path: Path, postgres_server: PostgresServer) -> None:
    source = _filled(tmp_path / "a", postgres_server.new_database())
    manifest = create_backup(source, tmp_path / "backup").manifest
    assert manifest["profile"] == "distributed" and manifest["database"] == "database/geoloc.pgdump"
    assert (tmp_path / "backup" / "database" / "geoloc.pgdump").read_bytes()[:5] == b"PGDMP"
    target = _deployment(tmp_path / "b", postgres_server.new_database())
    restore_backup(target, tmp_path / "backup")
    assert _jobs(target) == _jobs(source)
    assert (target.data_dir / "images" / "1" / "abc.jpg").read_text() == "photo"
    db = connect(target.database)
    try:
        assert table_counts(db)["jobs"] == 2
        new_id = job_store.enqueue_job(db, "k", AnyPayload(x=3))
        assert new_id == 3, "identity sequences restored: new rows do not collide"
    finally:
        db.close()
    with pytest.raises(BackupError, match=r"already holds data \(3 jobs rows"):
        restore_backup(target, tmp_path / "backup")
    with pytest.raises(BackupError, match="the backup is of the distributed profile; the target is embedded"):
        restore_backup(_deployment(tmp_path / "c"), tmp_path / "backup")
