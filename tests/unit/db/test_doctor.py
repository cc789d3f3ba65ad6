"""``db.doctor``: each check finds what a crash leaves behind, each repair fixes it once and says what it did.

Real databases (SQLite, and PostgreSQL for the checks that read rows) and real files in ``tmp_path``.
"""

from __future__ import annotations

import os
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from pydantic import ConfigDict

from contracts.jobs import LABEL_REFERENCE, LOCALIZE_QUERY, JobPayload, LabelReferencePayload, LocalizeQueryPayload
from contracts.queries import QueryParams
from db import Database, connect, transaction
from db import jobs as job_store
from db import maps as map_store
from db import queries as query_store
from db import references as reference_store
from db.doctor import DoctorError, examine, examine_deployment, requeue_or_fail
from db.doctor_checks import StuckJob, process_running
from db.files import DirectoryStore, open_store
from db.records import NewReference
from tests.conftest import Profile


class AnyPayload(JobPayload):
    """A test job's payload: any fields."""

    model_config = ConfigDict(extra="allow")


@dataclass
class Deployment:
    """A migrated database and its file store with one map, one reference and one query, each with its file."""

    db: Database
    store: DirectoryStore
    map_id: int
    reference_id: int
    reference_job: int
    query_id: int
    query_job: int

    def path_of(self, table: str, row_id: int) -> Path:
        column = "source_path" if table == "maps" else "image_path"
        key = self.db.execute(f"SELECT {column} FROM {table} WHERE id = ?", (row_id,)).fetchone()[0]
        return self.store.local_path(key)

    def job(self, job_id: int) -> dict[str, object]:
        return next(self.db.query("SELECT * FROM jobs WHERE id = ?", (job_id,)))


def _put(store: DirectoryStore, key: str, content: bytes = b"photo", age_s: float = 3600.0) -> None:
    """A stored file ``age_s`` seconds old."""
    path = store.local_path(key)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(content)
    stamp = time.time() - age_s
    os.utime(path, (stamp, stamp))


@pytest.fixture
def deployment(tmp_path: Path, profile: Profile) -> Iterator[Deployment]:
    target, _ = profile.new_deployment(tmp_path / "data")
    store = open_store(tmp_path / "data")
    db = connect(target)
    with transaction(db):
        map_id = map_store.insert_pending_map(
            db, name="m", source_filename="m.geojson", source_format="geojson", source_path="maps/m.geojson",
            sha256="m" * 64, size_bytes=5,
        )  # fmt: skip
        map_job = job_store.enqueue_job(db, "load_map", AnyPayload(map_id=map_id), map_id=map_id)
        db.execute("UPDATE maps SET job_id = ?, status = 'done' WHERE id = ?", (map_job, map_id))
        db.execute("UPDATE jobs SET status = 'done' WHERE id = ?", (map_job,))
        reference_id = reference_store.insert_reference(
            db,
            NewReference(
                map_id=map_id, image_path=f"images/{map_id}/r.jpg", original_filename="r.jpg", sha256="r" * 64,
                size_bytes=5, image_format="jpeg", width=64, height=64, gps_lat=60.17, gps_lon=24.94,
                position_source="request",
            ),
        )  # fmt: skip
        payload = LabelReferencePayload(reference_id=reference_id, map_id=map_id)
        reference_job = job_store.enqueue_job(db, LABEL_REFERENCE, payload, map_id=map_id, reference_id=reference_id)
        reference_store.set_reference_job(db, reference_id, reference_job)
        query_id = query_store.insert_query(
            db, map_id=map_id, params=QueryParams(top_n=1, k=1), image_path=f"queries/{map_id}/q.jpg", sha256="q" * 64
        )
        query_job = job_store.enqueue_job(db, LOCALIZE_QUERY, LocalizeQueryPayload(query_id=query_id, map_id=map_id))
        query_store.set_query_job(db, query_id, query_job)
    for key in ("maps/m.geojson", f"images/{map_id}/r.jpg", f"queries/{map_id}/q.jpg"):
        _put(store, key)
    try:
        yield Deployment(db, store, map_id, reference_id, reference_job, query_id, query_job)
    finally:
        db.close()


def test_a_consistent_deployment_is_clean(deployment: Deployment, profile: Profile) -> None:
    report = examine(deployment.db, deployment.store, repair=True, grace_s=0)
    assert report.clean and report.findings == [], report.findings
    assert report.integrity == (None if profile.distributed else "ok")
    assert report.checked == {"stored_files": 3, "rows_with_files": 3, "running_jobs": 0, "workers": 0}
    assert report.to_json()["counts"] == dict.fromkeys(report.counts(), 0)


def test_orphaned_and_temporary_files_are_reported_then_deleted(deployment: Deployment) -> None:
    store = deployment.store
    _put(store, "images/1/orphan.jpg")
    _put(store, "queries/1/young.jpg", age_s=5)  # younger than the grace: an upload may be about to commit it
    _put(store, "tmp/upload-0123.part")

    found = examine(deployment.db, store, grace_s=60)
    assert [(f.check, f.subject, f.repair) for f in found.findings] == [
        ("orphaned_file", "images/1/orphan.jpg", None),
        ("temp_file", "tmp/upload-0123.part", None),
    ]
    assert not found.clean and store.local_path("images/1/orphan.jpg").exists(), "a report changes nothing"

    repaired = examine(deployment.db, store, repair=True, grace_s=60)
    assert [(f.check, f.repair) for f in repaired.findings] == [("orphaned_file", "deleted"), ("temp_file", "deleted")]
    assert repaired.clean
    assert not store.local_path("images/1/orphan.jpg").exists()
    assert not store.local_path("tmp/upload-0123.part").exists()
    assert store.local_path("queries/1/young.jpg").exists()
    assert store.local_path(f"images/{deployment.map_id}/r.jpg").exists(), "a file with its row stays"
    assert examine(deployment.db, store, grace_s=60).findings == []


def test_rows_whose_file_is_gone_are_failed_with_the_reason_and_kept(deployment: Deployment) -> None:
    db = deployment.db
    for table, row_id in (("reference_images", deployment.reference_id), ("queries", deployment.query_id)):
        deployment.path_of(table, row_id).unlink()

    found = examine(db, deployment.store, grace_s=0)
    assert {(f.check, f.subject) for f in found.findings} == {
        ("missing_file", f"reference {deployment.reference_id}"),
        ("missing_file", f"query {deployment.query_id}"),
    }
    assert reference_store.get_reference(db, deployment.reference_id)["status"] == "queued"  # type: ignore[index]

    repaired = examine(db, deployment.store, repair=True, grace_s=0)
    assert repaired.clean and all(f.repair and f.repair.startswith("marked failed") for f in repaired.findings)
    reference = reference_store.get_reference(db, deployment.reference_id)
    assert reference is not None and reference["status"] == "failed"
    assert reference["error"] == f"the stored file images/{deployment.map_id}/r.jpg is missing (found by geoloc doctor)"
    for job_id in (deployment.reference_job, deployment.query_job):
        job = deployment.job(job_id)
        assert job["status"] == "failed" and "is missing (found by geoloc doctor)" in str(job["error"]), job
    query = query_store.get_query(db, deployment.query_id)
    assert query is not None and query["status"] == "failed"
    assert examine(db, deployment.store, grace_s=0).findings == [], "a failed row is accounted for"


def test_a_map_whose_source_is_gone_is_failed_with_a_code(deployment: Deployment) -> None:
    deployment.path_of("maps", deployment.map_id).unlink()
    report = examine(deployment.db, deployment.store, repair=True, grace_s=0)
    assert [(f.check, f.subject) for f in report.findings] == [("missing_file", f"map {deployment.map_id}")]
    row = map_store.get_map(deployment.db, deployment.map_id)
    assert row is not None and (row["status"], row["error_code"]) == ("failed", "stored_file_missing")


def _claim_as(db: Database, worker_id: str, pid: int, lease_s: float = 60.0) -> int:
    """Register a worker with ``pid`` on this host and let it claim the next job; the job's id."""
    job_store.register_worker(db, worker_id, pid, os.uname().nodename)
    job = job_store.claim_job(db, worker_id, lease_s)
    assert job is not None
    return int(job["id"])


def _dead_pid() -> int:
    """The pid of a process that has exited (and was reaped)."""
    process = subprocess.Popen(["true"])
    process.wait()
    return process.pid


def test_a_job_whose_worker_died_is_queued_again_and_the_worker_stopped(deployment: Deployment) -> None:
    db = deployment.db
    dead = _claim_as(db, "host:dead:1", _dead_pid())
    alive = _claim_as(db, "host:alive:1", os.getpid())

    found = examine(db, deployment.store, grace_s=0)
    assert {(f.check, f.subject) for f in found.findings} == {
        ("dead_worker", "worker host:dead:1"),
        ("stuck_job", f"job {dead} (label_reference)"),
    }, "a job whose worker runs and renews its lease is not stuck"

    repaired = examine(db, deployment.store, repair=True, grace_s=0)
    assert repaired.clean
    job = deployment.job(dead)
    assert (job["status"], job["attempts"], job["lease_owner"]) == ("queued", 1, None)
    assert "worker lost: its worker host:dead:1 is gone during attempt 1 of 3 (queued again by geoloc doctor)" in str(
        job["error"]
    )
    assert deployment.job(alive)["status"] == "running"
    stopped = db.execute("SELECT stopped_at FROM workers WHERE worker_id = 'host:dead:1'").fetchone()[0]
    assert stopped is not None
    assert job_store.claim_job(db, "host:next:1", 60.0) is not None, "the job can be claimed again"


def test_a_stuck_job_on_its_last_attempt_fails_with_worker_lost(deployment: Deployment) -> None:
    db = deployment.db
    db.execute("UPDATE jobs SET max_attempts = 1")
    job_id = _claim_as(db, "host:w:1", os.getpid(), lease_s=60.0)
    db.execute("UPDATE jobs SET lease_expires_at = ? WHERE id = ?", (time.time() - 5, job_id))  # stopped renewing

    report = examine(db, deployment.store, repair=True, grace_s=0)
    assert [f.check for f in report.findings] == ["stuck_job"] and report.clean
    job = deployment.job(job_id)
    assert job["status"] == "failed" and job["finished_at"] is not None
    assert "its lease expired" in str(job["error"]) and "attempt 1 of 1 (failed by geoloc doctor)" in str(job["error"])


def test_a_job_taken_over_meanwhile_is_left_to_its_new_owner(deployment: Deployment) -> None:
    db = deployment.db
    job_id = _claim_as(db, "host:new:1", os.getpid())
    stale = StuckJob(job_id, LABEL_REFERENCE, 1, 3, "host:old:1", "its worker host:old:1 is gone")
    assert requeue_or_fail(db, stale, now=time.time()) is None
    assert deployment.job(job_id)["status"] == "running"


def test_pending_work_whose_job_is_done_or_gone_is_failed(deployment: Deployment) -> None:
    db = deployment.db
    db.execute("UPDATE jobs SET status = 'done' WHERE id = ?", (deployment.reference_job,))
    db.execute("DELETE FROM jobs WHERE id = ?", (deployment.query_job,))

    report = examine(db, deployment.store, repair=True, grace_s=0)
    assert [(f.check, f.subject, f.problem) for f in report.findings] == [
        ("unfinished_work", f"reference {deployment.reference_id}",
         f"still pending, but its job {deployment.reference_job} is done"),
        ("unfinished_work", f"query {deployment.query_id}",
         f"still pending, but its job {deployment.query_job} is gone"),
    ]  # fmt: skip
    assert report.clean
    reference = reference_store.get_reference(db, deployment.reference_id)
    assert reference is not None and reference["status"] == "failed"
    assert str(reference["error"]).startswith("nothing would finish it: its job")


def test_a_damaged_sqlite_database_is_reported_and_never_repaired(tmp_path: Path) -> None:
    target, _ = Profile("embedded").new_deployment(tmp_path / "data")
    raw = sqlite3.connect(str(target))
    raw.execute("PRAGMA foreign_keys = OFF")
    raw.execute("INSERT INTO labels (reference_id, identity_npz, created_at) VALUES (42, x'00', 0)")
    raw.commit()
    raw.close()
    db = connect(target)
    try:
        report = examine(db, open_store(tmp_path / "data"), repair=True, grace_s=0)
    finally:
        db.close()
    assert [(f.check, f.problem, f.repair) for f in report.findings] == [
        ("integrity", "row 42 of labels refers to a missing row of reference_images", None)
    ]
    assert not report.clean and report.integrity is not None and "labels" in report.integrity


def test_a_deployment_without_a_current_database_is_refused(tmp_path: Path) -> None:
    with pytest.raises(DoctorError, match="no database at"):
        examine_deployment(tmp_path / "absent.sqlite3", tmp_path)
    assert not (tmp_path / "absent.sqlite3").exists(), "the doctor creates no database"
    sqlite3.connect(str(tmp_path / "old.sqlite3")).close()
    with pytest.raises(DoctorError, match="start the service once"):
        examine_deployment(tmp_path / "old.sqlite3", tmp_path)


def test_process_running() -> None:
    assert process_running(os.getpid())
    assert not process_running(_dead_pid())
