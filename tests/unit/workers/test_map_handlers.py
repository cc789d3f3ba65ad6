"""The map job (``load_map``) on a real SQLite database: idempotent, failing clearly, progress at a bounded rate."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from contracts.jobs import LoadMapPayload
from contracts.settings import get_settings
from db import Database, connect, migrate, transaction
from db import maps as map_store
from db.files import open_store
from workers.handlers import PermanentJobError
from workers.map_handlers import ProgressWriter, load_map_job

HALL = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "properties": {"name": "Test hall", "height": 12},
            "geometry": {
                "type": "Polygon",
                "coordinates": [
                    [[24.94, 60.17], [24.9402, 60.17], [24.9402, 60.1701], [24.94, 60.1701], [24.94, 60.17]]
                ],
            },
        }
    ],
}


@pytest.fixture
def db(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Database]:
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.delenv("GEOLOC_DATABASE_URL", raising=False)
    (tmp_path / "data").mkdir()
    database = connect(get_settings().database)
    migrate(database)
    yield database
    database.close()


def _pending(db: Database, content: bytes, filename: str = "town.geojson") -> int:
    key = f"maps/{len(content)}-{filename}"
    path = open_store(get_settings().file_store_dir).local_path(key)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(content)
    with transaction(db):
        return map_store.insert_pending_map(
            db,
            name="town",
            source_filename=filename,
            source_format="geojson",
            source_path=key,
            sha256=f"{len(content):064d}",
            size_bytes=len(content),
        )


def test_a_map_job_stores_the_map_once_however_often_it_runs(db: Database) -> None:
    map_id = _pending(db, json.dumps(HALL).encode())
    first = load_map_job(db, LoadMapPayload(map_id=map_id))
    row = map_store.get_map(db, map_id)
    assert row is not None and row["status"] == "done" and row["building_count"] == 1 == first.buildings
    assert 60.16 < row["min_lat"] < row["max_lat"] < 60.18 and row["parsed_buildings"] == 1
    with transaction(db):  # as if the worker crashed after the store, before the job was marked done
        db.execute("UPDATE maps SET status = 'queued' WHERE id = ?", (map_id,))
    again = load_map_job(db, LoadMapPayload(map_id=map_id))
    assert again == first
    assert len(map_store.list_buildings(db, map_id)) == 1
    assert db.execute("SELECT COUNT(*) FROM facades WHERE map_id = ?", (map_id,)).fetchone()[0] == 1


def test_a_file_that_is_not_a_map_fails_the_map_with_its_reason_and_no_path(db: Database) -> None:
    map_id = _pending(db, b'{"type": "FeatureCollection", "features": []}', "empty.geojson")
    with pytest.raises(PermanentJobError) as error:
        load_map_job(db, LoadMapPayload(map_id=map_id))
    row = map_store.get_map(db, map_id)
    assert row is not None and row["status"] == "failed" and row["error"] == str(error.value)
    assert row["error"].startswith("empty.geojson:") and str(get_settings().data_dir) not in row["error"]
    assert row["error_code"] and row["building_count"] == 0


def test_a_deleted_map_s_job_fails_for_good(db: Database) -> None:
    map_id = _pending(db, json.dumps(HALL).encode())
    with transaction(db):
        map_store.delete_map(db, map_id)
    with pytest.raises(PermanentJobError, match="no longer exists"):
        load_map_job(db, LoadMapPayload(map_id=map_id))


def test_progress_is_written_at_a_bounded_rate(db: Database) -> None:
    map_id = _pending(db, json.dumps(HALL).encode())
    writer = ProgressWriter(db, map_id, interval_s=60.0)
    for i in range(1, 1001):
        writer(i * 100, i)
    row = map_store.get_map(db, map_id)
    assert row is not None and (row["parsed_elements"], row["parsed_buildings"]) == (100, 1)  # the first only
