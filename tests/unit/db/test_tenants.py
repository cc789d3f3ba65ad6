"""``maps.tenant`` (migration 8) on both engines: old maps are untenanted, lists and the duplicate check filter."""

from __future__ import annotations

from pathlib import Path

import pytest

from contracts.jobs import LABEL_REFERENCE, LabelReferencePayload
from db import LATEST_VERSION, Database, connect, migrate, transaction
from db import jobs as job_store
from db import maps as map_store
from tests.conftest import Profile
from tests.unit.db.test_db import add_map, small_map_content


def _insert(db: Database, tenant: str | None, sha256: str = "0" * 64) -> int:
    with transaction(db):
        return map_store.insert_map(
            db,
            name=f"map of {tenant}",
            source_filename="t.geojson",
            source_format="geojson",
            source_path="maps/x.geojson",
            sha256=sha256,
            size_bytes=10,
            content=small_map_content(),
            tenant=tenant,
        )


def test_migration_8_leaves_old_maps_untenanted_and_lists_filter_by_tenant(
    tmp_path: Path, profile: Profile, monkeypatch: pytest.MonkeyPatch
) -> None:
    from db import migrations  # patched below: only the migrations up to 7 at first

    path = profile.postgres.new_empty_database() if profile.postgres else tmp_path / "v7.sqlite3"
    database = connect(path)
    try:
        with monkeypatch.context() as patched:
            patched.setattr(migrations, "MIGRATIONS", [m for m in migrations.MIGRATIONS if m[0] <= 7])
            assert migrate(database) == 7
        old_id = add_map(database)  # written without the column, as the service did before
        assert migrate(database) == LATEST_VERSION
        a_id, b_id = _insert(database, "team-a"), _insert(database, "team-b")
        old = map_store.get_map(database, old_id)
        assert old is not None and old["tenant"] is None
        assert [m["id"] for m in map_store.list_maps(database)] == [old_id]
        assert [m["id"] for m in map_store.list_maps(database, "team-a")] == [a_id]
        assert [m["id"] for m in map_store.list_maps(database, "team-b")] == [b_id]
        assert map_store.list_maps(database, "team-c") == []
        for tenant, expected in ((None, old_id), ("team-a", a_id), ("team-b", b_id)):
            found = map_store.find_map_by_sha256(database, "0" * 64, {}, tenant)
            assert found is not None and found["id"] == expected and found["tenant"] == tenant
        assert map_store.find_map_by_sha256(database, "0" * 64, {}, "team-c") is None

        def job_tenant(map_id: int | None, tenant: str | None = None) -> str | None:
            payload = LabelReferencePayload(reference_id=1, map_id=map_id or 0)
            job_id = job_store.enqueue_job(database, LABEL_REFERENCE, payload, map_id=map_id, tenant=tenant)
            job = job_store.get_job(database, job_id)
            assert job is not None
            return job["tenant"]

        assert job_tenant(a_id) == "team-a" and job_tenant(old_id) is None, "a job takes its map's tenant"
        assert job_tenant(None, "team-b") == "team-b" and job_tenant(None) is None, "or the one given"
    finally:
        database.close()
