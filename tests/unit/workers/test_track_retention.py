"""Retention of tracks: a finished track older than the retention goes with its frames, their jobs and photos.

A frame (a query row with a ``track_id``) is never pruned alone, however old: it goes with its track; a track still
waiting stays; a photo a lone query still uses stays.
"""

from __future__ import annotations

import time
from pathlib import Path

from contracts.jobs import LOCATE_TRACK, LocateTrackPayload
from contracts.queries import QueryParams
from db import Database, connect, migrate, transaction
from db import jobs as job_store
from db import queries as query_store
from db import tracks as track_store
from workers.retention import purge_expired_queries

DAY_S = 86400.0


def _map(db: Database) -> None:
    with transaction(db):
        db.execute(
            "INSERT INTO maps (name, source_filename, source_format, source_path, sha256, size_bytes, min_lat, min_lon,"
            " max_lat, max_lon, origin_lat, origin_lon, building_count, facade_count, created_at)"
            " VALUES ('m', 'm', 'geojson', 'maps/m', 's', 1, 0, 0, 1, 1, 0, 0, 0, 0, 0)"
        )


def _track(db: Database, data_dir: Path, photos: list[str], *, age_s: float, finished: bool) -> tuple[int, list[int]]:
    query_ids = []
    with transaction(db):
        track_id = track_store.insert_track(db, map_id=1, params={"order": "sent"})
        for index, photo in enumerate(photos):
            (data_dir / photo).parent.mkdir(parents=True, exist_ok=True)
            (data_dir / photo).write_bytes(b"photo")
            query_id = query_store.insert_query(db, map_id=1, params=QueryParams(top_n=1, k=1), image_path=photo)
            track_store.attach_frame(db, query_id, track_id, index)
            query_ids.append(query_id)
        job_id = job_store.enqueue_job(db, LOCATE_TRACK, LocateTrackPayload(track_id=track_id, map_id=1), map_id=1)
        track_store.set_track_job(db, track_id, job_id)
        created = time.time() - age_s
        db.execute("UPDATE tracks SET created_at = ? WHERE id = ?", (created, track_id))
        db.execute("UPDATE queries SET created_at = ? WHERE track_id = ?", (created, track_id))
        if finished:
            track_store.update_track_result(db, track_id, status="done", result={"frames": []})
            db.execute("UPDATE jobs SET status = 'done' WHERE id = ?", (job_id,))
    return track_id, query_ids


def test_old_finished_tracks_go_with_their_frames_and_photos(tmp_path: Path) -> None:
    db = connect(tmp_path / "geoloc.sqlite3")
    migrate(db)
    _map(db)
    old, old_frames = _track(db, tmp_path, ["queries/1/a.jpg", "queries/1/b.jpg"], age_s=3 * DAY_S, finished=True)
    waiting, waiting_frames = _track(db, tmp_path, ["queries/1/c.jpg"], age_s=3 * DAY_S, finished=False)
    with transaction(db):  # a lone, recent query of the same photo as one of the old track's frames
        lone = query_store.insert_query(db, map_id=1, params=QueryParams(top_n=1, k=1), image_path="queries/1/b.jpg")
    # The waiting track's frame is old and its job is queued; the old track's frames are old and their job done:
    # neither kind of frame is pruned as a lone query.
    assert purge_expired_queries(db, tmp_path, retention_s=DAY_S) == 1
    assert track_store.get_track(db, old) is None and track_store.get_track(db, waiting) is not None
    remaining = {row["id"] for row in db.query("SELECT id FROM queries")}
    assert remaining == {*waiting_frames, lone}
    assert not (tmp_path / "queries/1/a.jpg").exists(), "the deleted frame's photo is gone"
    assert (tmp_path / "queries/1/b.jpg").exists(), "a photo a lone query still uses stays"
    assert (tmp_path / "queries/1/c.jpg").exists()
    assert [row["kind"] for row in db.query("SELECT kind FROM jobs")] == [LOCATE_TRACK], "the done job went too"
    assert all(query_store.get_query(db, q) is None for q in old_frames)
    db.close()


def test_deleting_a_track_deletes_its_frames(tmp_path: Path) -> None:
    db = connect(tmp_path / "geoloc.sqlite3")
    migrate(db)
    _map(db)
    track_id, frames = _track(db, tmp_path, ["queries/1/a.jpg", "queries/1/a.jpg"], age_s=0, finished=False)
    assert [row["frame_index"] for row in track_store.track_frames(db, track_id)] == [0, 1]
    assert all(query_store.get_query(db, q)["job_id"] == track_store.get_track(db, track_id)["job_id"] for q in frames)  # type: ignore[index]
    with transaction(db):
        paths = track_store.delete_track(db, track_id)
    assert paths == ["queries/1/a.jpg", "queries/1/a.jpg"]
    assert list(db.query("SELECT id FROM queries")) == []
    with transaction(db):
        assert track_store.delete_track(db, track_id) is None
    db.close()
