"""Retention: finished queries (photo, answer, job) older than ``GEOLOC_QUERY_RETENTION_S`` are deleted.

The workers delete them; queries still waiting or running, and references, are never deleted implicitly.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from contracts.jobs import LOCALIZE_QUERY, LocalizeQueryPayload
from contracts.queries import QueryParams
from db import Database, connect, migrate, transaction
from db import jobs as job_store
from db import queries as query_store
from db import references as reference_store
from db.records import NewReference
from tests import TESTS_DIR
from tests.conftest import Profile
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    ONE_BUILDING,
    WRITE_KEY,
    jpeg_bytes,
    read_rows,
    running_service,
    wait_for,
)
from workers.retention import purge_expired_queries

PLUGIN = TESTS_DIR / "answer_plugin.py"
DAY_S = 86400.0


def _query(db: Database, data_dir: Path, map_id: int, photo: str, *, age_s: float, finished: bool) -> int:
    (data_dir / photo).parent.mkdir(parents=True, exist_ok=True)
    (data_dir / photo).write_bytes(b"photo")
    with transaction(db):
        params = QueryParams(top_n=10, k=4)
        query_id = query_store.insert_query(db, map_id=map_id, params=params, image_path=photo, sha256="x")
        payload = LocalizeQueryPayload(query_id=query_id, map_id=map_id)
        job_id = job_store.enqueue_job(db, LOCALIZE_QUERY, payload, map_id=map_id)
        query_store.set_query_job(db, query_id, job_id)
        created = time.time() - age_s
        db.execute("UPDATE queries SET created_at = ? WHERE id = ?", (created, query_id))
        if finished:
            db.execute("UPDATE jobs SET status = 'failed' WHERE id = ?", (job_id,))
    return query_id


def test_purge_deletes_only_old_finished_queries_and_photos_no_one_uses(tmp_path: Path) -> None:
    db = connect(tmp_path / "geoloc.sqlite3")
    migrate(db)
    with transaction(db):
        db.execute(
            "INSERT INTO maps (name, source_filename, source_format, source_path, sha256, size_bytes, min_lat, min_lon,"
            " max_lat, max_lon, origin_lat, origin_lon, building_count, facade_count, created_at)"
            " VALUES ('m', 'm', 'geojson', 'maps/m', 's', 1, 0, 0, 1, 1, 0, 0, 0, 0, 0)"
        )
        reference_id = reference_store.insert_reference(
            db,
            NewReference(
                map_id=1, image_path="images/1/r.jpg", original_filename=None, sha256="r", size_bytes=1,
                image_format="JPEG", width=64, height=64, gps_lat=0.5, gps_lon=0.5, position_source="request",
            ),
        )  # fmt: skip
        db.execute("UPDATE reference_images SET created_at = 0 WHERE id = ?", (reference_id,))
    old_done = _query(db, tmp_path, 1, "queries/1/a.jpg", age_s=3 * DAY_S, finished=True)
    old_waiting = _query(db, tmp_path, 1, "queries/1/b.jpg", age_s=3 * DAY_S, finished=False)
    old_shared = _query(db, tmp_path, 1, "queries/1/c.jpg", age_s=3 * DAY_S, finished=True)
    new_shared = _query(db, tmp_path, 1, "queries/1/c.jpg", age_s=60, finished=True)  # the same photo, asked again

    assert purge_expired_queries(db, tmp_path, retention_s=DAY_S) == 2
    remaining = {row["id"] for row in db.query("SELECT id FROM queries")}
    assert remaining == {old_waiting, new_shared}
    assert not (tmp_path / "queries/1/a.jpg").exists(), "the photo of a deleted query is gone"
    assert (tmp_path / "queries/1/c.jpg").exists(), "a photo another query still uses stays"
    assert {row["payload"] for row in db.query("SELECT payload FROM jobs")} == {
        json.dumps({"query_id": old_waiting, "map_id": 1}),
        json.dumps({"query_id": new_shared, "map_id": 1}),
    }, "the jobs of deleted queries go with them"
    assert reference_store.get_reference(db, reference_id) is not None, "references are never purged"
    assert old_done not in remaining and old_shared not in remaining

    assert purge_expired_queries(db, tmp_path, retention_s=DAY_S, now=time.time() + 2 * DAY_S) == 1
    assert not (tmp_path / "queries/1/c.jpg").exists(), "gone once the last query using it is"
    db.close()


@pytest.mark.slow
def test_workers_apply_the_retention(tmp_path: Path, built_models: Path, profile: Profile) -> None:
    data_dir = tmp_path / "data"
    env = {"GEOLOC_QUERY_RETENTION_S": "3", "GEOLOC_WORKER_PLUGINS": str(PLUGIN), **profile.new_env()}
    with (
        running_service(data_dir, workers=1, models=built_models, **env) as service,
        service.client(WRITE_KEY) as client,
    ):
        files = {"file": ("hall.geojson", json.dumps(ONE_BUILDING).encode())}
        map_id = client.post("/v1/maps", files=files, data={"wait_s": "120", "name": "hall"}).json()["id"]
        reference = client.post(
            f"/v1/maps/{map_id}/references", files={"image": ("r.jpg", jpeg_bytes(seed=1))}, data=INSIDE_ONE_BUILDING
        ).json()
        query = client.post(
            f"/v1/maps/{map_id}/queries",
            files={"image": ("q.jpg", jpeg_bytes(seed=2))},
            data={"top_n": "1", "use_exif_gps": "false", "wait_s": "30"},
        ).json()
        assert query["status"] == "done", query
        photo = read_rows(service.database, "SELECT image_path FROM queries WHERE id = ?", (query["id"],))[0]
        assert (data_dir / photo["image_path"]).is_file()
        wait_for(lambda: client.get(f"/v1/queries/{query['id']}").status_code == 404, timeout=30,
                 what="the query to expire")  # fmt: skip
        assert not (data_dir / photo["image_path"]).exists()
        assert client.get(f"/v1/jobs/{query['job_id']}").status_code == 404
        kept = client.get(f"/v1/references/{reference['id']}")
        assert kept.status_code == 200, "references are never deleted implicitly"
        image = read_rows(service.database, "SELECT image_path FROM reference_images WHERE id = ?", (reference["id"],))
        assert (data_dir / image[0]["image_path"]).is_file()
