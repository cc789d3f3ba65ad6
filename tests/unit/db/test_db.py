"""Database, on both engines (SQLite and PostgreSQL).

Migrations, connection settings, map/reference storage, the SBoW index's consistency, job states and
concurrent claims.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from pydantic import ConfigDict

from contracts.jobs import (
    LABEL_REFERENCE,
    LOAD_MAP,
    LOCALIZE_QUERY,
    LOCATE_TRACK,
    JobPayload,
    LabelReferencePayload,
    LocalizeQueryPayload,
    LocateTrackPayload,
)
from contracts.queries import QueryParams
from contracts.references import ReferenceKeypoints, ReferenceLabelArrays
from db import LATEST_VERSION, Database, connect, migrate, migrations, sbow, schema_version, transaction
from db import jobs as job_store
from db import maps as map_store
from db import queries as query_store
from db import references as reference_store
from db import tracks as track_store
from db.records import NewReference
from db.stats import table_counts
from tests.conftest import Profile


class AnyPayload(JobPayload):
    """A test job's payload: any fields."""

    model_config = ConfigDict(extra="allow")


def tiny_keypoints(n: int, dim: int = 8) -> ReferenceKeypoints:
    """``n`` keypoints of zeros (``dim``-dimensional descriptors), no identities, anchors or position."""
    return ReferenceKeypoints.from_arrays(
        {
            "xy": np.zeros((n, 2)),
            "descriptors": np.zeros((n, dim)),
            "sizes": np.zeros(n),
            "angles": np.zeros(n),
            "responses": np.zeros(n),
            "image_shape": np.array([4, 4]),
            "scale": np.array(1.0),
            "identity": np.zeros((n, 0)),
            "building_ids": np.zeros(0, np.int64),
        }
    )


@pytest.fixture
def db_path(tmp_path: Path, profile: Profile) -> Path | str:
    """A fresh migrated database of the profile: a SQLite file or a PostgreSQL URL."""
    target, _ = profile.new_deployment(tmp_path)
    return target


@pytest.fixture
def db(db_path: Path | str) -> Iterator[Database]:
    database = connect(db_path)
    yield database
    database.close()


def small_map_content() -> map_store.MapContent:
    square = {"type": "Polygon", "coordinates": [[[24.94, 60.17], [24.941, 60.17], [24.941, 60.171], [24.94, 60.17]]]}
    return map_store.MapContent(
        bbox_wgs84=(60.169, 24.939, 60.172, 24.942),
        origin_lat=60.1705,
        origin_lon=24.9405,
        buildings=[
            map_store.BuildingRow(0, "way/1", "Town hall", 20.0, square),
            map_store.BuildingRow(1, "way/2", None, 12.0, square),
        ],
        facade_arrays={"start": np.zeros((5, 2)), "building_id": np.array([0, 0, 0, 1, 1], dtype=np.int32)},
        repair_report={"format": "geojson"},
    )


def add_map(db) -> int:
    with transaction(db):
        return map_store.insert_map(
            db,
            name="test",
            source_filename="t.geojson",
            source_format="geojson",
            source_path="maps/x.geojson",
            sha256="0" * 64,
            size_bytes=10,
            content=small_map_content(),
        )


def add_reference(db, map_id: int, sha: str) -> int:
    with transaction(db):
        return reference_store.insert_reference(
            db,
            NewReference(
                map_id=map_id,
                image_path=f"images/{map_id}/{sha}.jpg",
                original_filename="a.jpg",
                sha256=sha,
                size_bytes=100,
                image_format="JPEG",
                width=640,
                height=480,
                gps_lat=60.17,
                gps_lon=24.94,
                position_source="request",
            ),
        )


def test_migrations_are_idempotent(db_path: Path | str) -> None:
    db = connect(db_path)
    assert schema_version(db) == LATEST_VERSION
    assert migrate(db) == LATEST_VERSION
    assert migrate(db) == LATEST_VERSION
    rows = list(db.query("SELECT version FROM schema_migrations"))
    assert [r["version"] for r in rows] == list(range(1, LATEST_VERSION + 1))  # contiguous: no number skipped
    db.close()


def test_concurrent_first_migrations_apply_once(tmp_path: Path, profile: Profile) -> None:
    """Four connections opening a new database at once all migrate it (SQLite: the WAL switch is raced, retried).

    SQLite runs 20 rounds (the race of a file's first open shows in about one in twenty); PostgreSQL one (its
    race is the migration lock's).
    """
    for round_ in range(1 if profile.postgres else 20):
        _first_migrations_race(tmp_path / f"race-{round_}.sqlite3", profile)


def _first_migrations_race(sqlite_path: Path, profile: Profile) -> None:
    path = profile.postgres.new_empty_database() if profile.postgres else sqlite_path
    results: list[int] = []
    errors: list[BaseException] = []

    def run() -> None:
        try:
            database = connect(path)
            results.append(migrate(database))
            database.close()
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=run) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors
    assert results == [LATEST_VERSION] * 4
    database = connect(path)
    assert database.execute("SELECT COUNT(*) FROM schema_migrations").fetchone()[0] == LATEST_VERSION
    database.close()


def test_migration_5_adds_the_compass_accuracy_to_an_existing_database(
    tmp_path: Path, profile: Profile, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A database at version 4 with a reference keeps it; the reference reads a NULL accuracy (a stated heading)."""
    path = profile.postgres.new_empty_database() if profile.postgres else tmp_path / "v4.sqlite3"
    database = connect(path)
    with monkeypatch.context() as patched:
        patched.setattr(migrations, "MIGRATIONS", [m for m in migrations.MIGRATIONS if m[0] <= 4])
        assert migrate(database) == 4
    map_id = add_map(database)
    with transaction(database):  # the version-4 columns only, as the service wrote them before
        old_id = database.insert_returning_id(
            "INSERT INTO reference_images (map_id, image_path, original_filename, sha256, size_bytes, image_format,"
            " width, height, gps_lat, gps_lon, position_source, prior_heading_deg, status, created_at, updated_at)"
            " VALUES (?, 'images/old.jpg', 'old.jpg', ?, 10, 'JPEG', 640, 480, 60.17, 24.94, 'exif', 90.0,"
            " 'done', 0, 0)",
            (map_id, "a" * 64),
        )
    assert migrate(database) == LATEST_VERSION
    old = reference_store.get_reference(database, old_id)
    assert old is not None and old["prior_heading_deg"] == 90.0 and old["prior_heading_accuracy_deg"] is None
    with transaction(database):
        new_id = reference_store.insert_reference(
            database,
            NewReference(
                map_id=map_id,
                image_path="images/new.jpg",
                original_filename="new.jpg",
                sha256="b" * 64,
                size_bytes=10,
                image_format="JPEG",
                width=640,
                height=480,
                gps_lat=60.17,
                gps_lon=24.94,
                position_source="exif",
                prior_heading_deg=123.5,
                prior_heading_accuracy_deg=20.0,
            ),
        )
    new = reference_store.get_reference(database, new_id)
    assert new is not None and (new["prior_heading_deg"], new["prior_heading_accuracy_deg"]) == (123.5, 20.0)
    database.close()


def test_migration_6_adds_the_map_attribution_to_an_existing_database(
    tmp_path: Path, profile: Profile, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A map stored at version 5 reads no stated attribution (the default applies); a new one keeps what it states."""
    path = profile.postgres.new_empty_database() if profile.postgres else tmp_path / "v5.sqlite3"
    database = connect(path)
    with monkeypatch.context() as patched:
        patched.setattr(migrations, "MIGRATIONS", [m for m in migrations.MIGRATIONS if m[0] <= 5])
        assert migrate(database) == 5
    old_id = add_map(database)  # written without the column, as the service did before
    assert migrate(database) == LATEST_VERSION
    old = map_store.get_map(database, old_id)
    assert old is not None and old["attribution"] is None and old["building_count"] == 2
    with transaction(database):
        new_id = map_store.insert_map(
            database,
            name="stated",
            source_filename="t.gpkg",
            source_format="gpkg",
            source_path="maps/y.gpkg",
            sha256="1" * 64,
            size_bytes=10,
            content=small_map_content(),
            attribution="© City of Helsinki, CC BY 4.0",
        )
    assert [m["attribution"] for m in map_store.list_maps(database)] == [None, "© City of Helsinki, CC BY 4.0"]
    assert map_store.get_map(database, new_id)["attribution"] == "© City of Helsinki, CC BY 4.0"
    database.close()


def test_workers_record_the_kinds_they_claim(tmp_path: Path, profile: Profile, monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker registered before migration 11 claims every kind; one registered after keeps its kinds."""
    path = profile.postgres.new_empty_database() if profile.postgres else tmp_path / "v10.sqlite3"
    database = connect(path)
    with monkeypatch.context() as patched:
        patched.setattr(migrations, "MIGRATIONS", [m for m in migrations.MIGRATIONS if m[0] <= 10])
        assert migrate(database) == 10
    database.execute(  # as a worker of version 10 registered itself
        "INSERT INTO workers (worker_id, pid, hostname, started_at, heartbeat_at) VALUES (?, ?, ?, ?, ?)",
        ("old", 1, "h", time.time(), time.time()),
    )
    assert migrate(database) == LATEST_VERSION
    job_store.register_worker(database, "maps", 2, "h", (LOAD_MAP,))
    job_store.register_worker(database, "all", 3, "h")
    job_store.register_worker(database, "two", 4, "h", (LABEL_REFERENCE, LOAD_MAP))
    kinds = {w["worker_id"]: job_store.claimed_kinds(w) for w in job_store.live_workers(database, 60)}
    assert kinds == {"old": (), "maps": (LOAD_MAP,), "all": (), "two": (LABEL_REFERENCE, LOAD_MAP)}
    job_store.register_worker(database, "maps", 5, "h")  # the same id started again without a restriction
    again = [w for w in job_store.live_workers(database, 60) if w["worker_id"] == "maps"]
    assert [job_store.claimed_kinds(w) for w in again] == [()]
    database.close()


def test_buildings_by_id(db) -> None:
    map_id = add_map(db)
    assert [b["building_id"] for b in map_store.list_buildings(db, map_id, building_ids=[1])] == [1]
    assert map_store.list_buildings(db, map_id, building_ids=[]) == []
    assert map_store.list_buildings(db, map_id, building_ids=[0, 1, 7])[0]["footprint_geojson"]["type"] == "Polygon"


def test_query_params_stored_before_the_compass_accuracy_still_load() -> None:
    from contracts.queries import QueryParams

    old = QueryParams.from_json({"top_n": 3, "k": 5, "prior_heading_deg": 45.0})
    assert old.prior_heading_deg == 45.0 and old.prior_heading_accuracy_deg is None
    assert "prior_heading_accuracy_deg" not in old.to_json()


def test_connection_settings(db) -> None:
    if db.is_postgres:  # autocommit, with lock waits bounded
        assert db.execute("SELECT current_setting('lock_timeout')").fetchone()[0] == "30s"
        assert not db.in_transaction
        return
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert db.execute("PRAGMA foreign_keys").fetchone()[0] == 1
    assert db.execute("PRAGMA busy_timeout").fetchone()[0] > 0


def test_map_round_trip_and_cascading_delete(db) -> None:
    map_id = add_map(db)
    row = map_store.get_map(db, map_id)
    assert row is not None and row["building_count"] == 2 and row["facade_count"] == 5
    assert [b["name"] for b in map_store.list_buildings(db, map_id)] == ["Town hall", None]
    facades = map_store.get_facade_arrays(db, map_id)
    assert facades is not None and facades["building_id"].tolist() == [0, 0, 0, 1, 1]
    ref = add_reference(db, map_id, "a" * 64)
    with transaction(db):
        labels = ReferenceLabelArrays.from_mask(np.arange(2), np.ones((4, 2)), np.ones((4, 4), bool), np.ones((2, 2)))
        reference_store.save_labels(db, ref, labels)
        reference_store.save_keypoints(db, ref, tiny_keypoints(3))
        sbow.save_vocabulary(db, map_id, {"centers": np.zeros((10, 8))})
        sbow.index_reference(db, map_id, ref, np.array([1, 2, 2]), np.ones(3))
        job_store.enqueue_job(
            db, LABEL_REFERENCE, LabelReferencePayload(reference_id=ref, map_id=map_id), map_id=map_id, reference_id=ref
        )
    with transaction(db):
        deleted = map_store.delete_map(db, map_id)
    assert deleted is not None and deleted["image_paths"] == [f"images/{map_id}/{'a' * 64}.jpg"]
    counts = table_counts(db)
    assert all(counts[t] == 0 for t in counts if t != "jobs"), counts
    assert [j["status"] for j in job_store.list_jobs(db)] == ["cancelled"]


def test_deleting_a_query_or_a_track_cancels_its_queued_job_and_leaves_a_running_one(db) -> None:
    map_id = add_map(db)
    with transaction(db):
        query_ids = [query_store.insert_query(db, map_id=map_id, params=QueryParams(top_n=5, k=4)) for _ in range(2)]
        track_id = track_store.insert_track(db, map_id=map_id, params={})
        jobs = [
            job_store.enqueue_job(db, LOCALIZE_QUERY, LocalizeQueryPayload(query_id=q, map_id=map_id), map_id=map_id)
            for q in query_ids
        ]
        jobs.append(
            job_store.enqueue_job(db, LOCATE_TRACK, LocateTrackPayload(track_id=track_id, map_id=map_id), map_id=map_id)
        )
        for query_id, job_id in zip(query_ids, jobs, strict=False):
            query_store.set_query_job(db, query_id, job_id)
        track_store.set_track_job(db, track_id, jobs[2])
    running = job_store.claim_job(db, "w1", 60.0, kinds=[LOCALIZE_QUERY])
    assert running is not None and running["id"] == jobs[0]
    with transaction(db):
        query_store.delete_query(db, query_ids[0])  # running: its worker finds the query gone and says so
        query_store.delete_query(db, query_ids[1])
        track_store.delete_track(db, track_id)
    statuses = {j["id"]: j["status"] for j in job_store.list_jobs(db)}
    assert statuses == {jobs[0]: "running", jobs[1]: "cancelled", jobs[2]: "cancelled"}


def ranked_references(db, map_id: int, query_words: np.ndarray) -> list[int]:
    """Reference ids with a positive score, best first (the method's scoring on the db postings)."""
    from geoloc.localize.retrieval import tfidf_scores

    p = sbow.postings_for_words(db, map_id, query_words)
    scores = tfidf_scores(query_words, p.word, p.doc, p.count, p.doc_lengths, p.n_docs)
    order = np.argsort(-scores, kind="stable")
    return [int(p.reference_ids[i]) for i in order if scores[i] > 0]


def test_sbow_index_follows_references(db) -> None:
    map_id = add_map(db)
    first = add_reference(db, map_id, "a" * 64)
    with transaction(db):
        sbow.index_reference(db, map_id, first, np.array([5, 5, 7]), np.ones(3))
    # retrieval works from the first reference on
    assert ranked_references(db, map_id, np.array([5, 9])) == [first]
    second = add_reference(db, map_id, "b" * 64)
    with transaction(db):
        sbow.index_reference(db, map_id, second, np.array([9, 9, 9, 7]), np.ones(4))
    assert ranked_references(db, map_id, np.array([9, 9]))[0] == second
    postings = sbow.postings_for_words(db, map_id, np.array([7]))
    assert postings.n_docs == 2 and sorted(postings.reference_ids.tolist()) == [first, second]
    # re-indexing replaces, never duplicates
    with transaction(db):
        sbow.index_reference(db, map_id, first, np.array([5]), np.ones(1))
    assert db.execute("SELECT COUNT(*) FROM sbow_postings WHERE reference_id = ?", (first,)).fetchone()[0] == 1
    # deleting a reference removes its postings in the same transaction
    with transaction(db):
        reference_store.delete_reference(db, second)
    assert db.execute("SELECT COUNT(*) FROM sbow_postings WHERE reference_id = ?", (second,)).fetchone()[0] == 0
    assert sbow.document_count(db, map_id) == 1
    # a failed transaction leaves the index as it was
    with pytest.raises(RuntimeError), transaction(db):
        sbow.index_reference(db, map_id, first, np.array([1, 2, 3]), np.ones(3))
        raise RuntimeError("crash mid-way")
    assert [r["word_id"] for r in db.query("SELECT word_id FROM sbow_postings WHERE reference_id = ?", (first,))] == [5]


def test_duplicate_reference_checksum_is_rejected_by_the_schema(db) -> None:
    map_id = add_map(db)
    add_reference(db, map_id, "c" * 64)
    with pytest.raises(Exception, match="(?i)unique"):
        add_reference(db, map_id, "c" * 64)


def test_job_retry_limit_keeps_the_error(db) -> None:
    job_id = job_store.enqueue_job(db, "k", AnyPayload(x=1), max_attempts=2)
    claimed = job_store.claim_job(db, "w1", lease_s=30)
    assert claimed is not None and claimed["id"] == job_id and claimed["attempts"] == 1
    assert job_store.claim_job(db, "w2", lease_s=30) is None  # leased
    assert job_store.fail_job(db, job_id, "w1", "boom 1", retry_delay_s=0) == "queued"
    again = job_store.claim_job(db, "w2", lease_s=30)
    assert again is not None and again["attempts"] == 2
    assert job_store.fail_job(db, job_id, "w2", "boom 2", retry_delay_s=0) == "failed"
    job = job_store.get_job(db, job_id)
    assert job is not None and job["status"] == "failed" and job["error"] == "boom 2"
    assert job_store.claim_job(db, "w3", lease_s=30) is None


def test_expired_lease_is_reclaimed_and_the_old_owner_cannot_finish(db) -> None:
    job_id = job_store.enqueue_job(db, "k", AnyPayload(), max_attempts=3)
    assert job_store.claim_job(db, "dead-worker", lease_s=0.05) is not None
    time.sleep(0.1)
    taken = job_store.claim_job(db, "new-worker", lease_s=30)
    assert taken is not None and taken["id"] == job_id and taken["attempts"] == 2
    assert not job_store.heartbeat_job(db, job_id, "dead-worker", 30)
    assert not job_store.complete_job(db, job_id, "dead-worker", {"stale": True})
    assert job_store.complete_job(db, job_id, "new-worker", {"ok": True})
    job = job_store.get_job(db, job_id)
    assert job is not None and job["status"] == "done" and job["result"] == {"ok": True}


def test_expired_lease_on_the_last_attempt_fails_the_job(db) -> None:
    job_id = job_store.enqueue_job(db, "k", AnyPayload(), max_attempts=1)
    assert job_store.claim_job(db, "dead-worker", lease_s=0.05) is not None
    time.sleep(0.1)
    assert job_store.claim_job(db, "other", lease_s=30) is None
    job = job_store.get_job(db, job_id)
    assert job is not None and job["status"] == "failed" and "lease expired" in job["error"]


def test_release_does_not_count_the_attempt(db) -> None:
    job_id = job_store.enqueue_job(db, "k", AnyPayload())
    assert job_store.claim_job(db, "w1", lease_s=30) is not None
    assert job_store.release_job(db, job_id, "w1")
    job = job_store.get_job(db, job_id)
    assert job is not None and job["status"] == "queued" and job["attempts"] == 0


def test_concurrent_claims_take_each_job_once(db_path: Path | str) -> None:
    """Workers claiming at once (own connections) never take the same job (SKIP LOCKED / the write lock)."""
    db = connect(db_path)
    job_ids = [job_store.enqueue_job(db, "k", AnyPayload(n=n)) for n in range(40)]
    db.close()
    claimed: list[int] = []
    errors: list[BaseException] = []

    def work(worker: str) -> None:
        database = connect(db_path)
        try:
            while (job := job_store.claim_job(database, worker, lease_s=30)) is not None:
                claimed.append(int(job["id"]))
        except BaseException as exc:
            errors.append(exc)
        finally:
            database.close()

    threads = [threading.Thread(target=work, args=(f"w{i}",)) for i in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors
    assert sorted(claimed) == job_ids
