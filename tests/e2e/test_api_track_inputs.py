"""A track's bad inputs against a real server with no workers (jobs stay queued): each a clear 4xx, nothing stored.

Too many frames (413), a frame that is not a photo (422 naming it), an unknown map (404), another map's queries
(422 ``foreign_query``), malformed priors and JSON bodies (422); and what a good request stores: one track, one
job, one query row per frame sharing the job, deleted with the track.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.conftest import Profile
from tests.service_fixtures import (
    ONE_BUILDING,
    RunningProcess,
    jpeg_bytes,
    read_rows,
    running_service,
    stored_files,
    table_counts,
)

pytestmark = pytest.mark.slow  # a real server on both profiles

MAX_FRAMES = 4
INSIDE = (60.1699, 24.9402)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[RunningProcess]:
    data_dir = tmp_path_factory.mktemp("track-inputs") / "data"
    env = {"GEOLOC_MAX_TRACK_FRAMES": str(MAX_FRAMES), "GEOLOC_RATE_LIMIT_PER_MIN": "100000"}
    with running_service(data_dir, workers=0, **env, **profile.new_env()) as running:
        yield running


def _map(client: httpx.Client, shift: float = 0.0) -> int:
    collection = json.loads(json.dumps(ONE_BUILDING))
    ring = collection["features"][0]["geometry"]["coordinates"][0]
    collection["features"][0]["geometry"]["coordinates"][0] = [[x + shift, y] for x, y in ring]
    files = {"file": (f"hall{shift}.geojson", json.dumps(collection).encode())}
    response = client.post("/v1/maps", files=files, data={"name": f"hall {shift}", "wait_s": "120"})
    assert response.status_code in (200, 201), response.text
    return int(response.json()["id"])


def _frames(n: int) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [("images", (f"f{i}.jpg", jpeg_bytes(320, 240, gps=INSIDE, seed=i), "image/jpeg")) for i in range(n)]


def _error(response: httpx.Response) -> dict[str, Any]:
    body = response.json()
    assert "Traceback" not in response.text and "/tmp" not in response.text, response.text
    return dict(body["error"])


def test_bad_tracks_get_a_clear_4xx_and_store_nothing(service: RunningProcess) -> None:
    with service.client() as client:
        map_id, other_id = _map(client), _map(client, 0.001)
        before = table_counts(service.database)
        files_before = stored_files(service.data_dir)

        too_many = client.post(f"/v1/maps/{map_id}/tracks", files=_frames(MAX_FRAMES + 1), data={"wait_s": "0"})
        assert too_many.status_code == 413, too_many.text
        err = _error(too_many)
        assert err["code"] == "too_many_frames" and err["details"]["limit_frames"] == MAX_FRAMES

        not_photo = [*_frames(2), ("images", ("notes.txt", b"not a photo at all", "text/plain"))]
        bad = client.post(f"/v1/maps/{map_id}/tracks", files=not_photo, data={"wait_s": "0"})
        assert bad.status_code == 422, bad.text
        err = _error(bad)
        assert err["details"]["frame"] == 2 and err["message"].startswith("frame 2:"), err

        unknown = client.post("/v1/maps/999999/tracks", files=_frames(2), data={"wait_s": "0"})
        assert unknown.status_code == 404 and _error(unknown)["code"] == "not_found"

        empty = client.post(f"/v1/maps/{map_id}/tracks", data={"wait_s": "0"})
        assert empty.status_code == 422 and "at least one frame" in _error(empty)["message"]

        bad_priors = client.post(
            f"/v1/maps/{map_id}/tracks", files=_frames(2), data={"wait_s": "0", "priors": '[{"lat": "north"}]'}
        )
        assert bad_priors.status_code == 422 and "priors" in _error(bad_priors)["message"]
        short = client.post(f"/v1/maps/{map_id}/tracks", files=_frames(2), data={"wait_s": "0", "priors": "[null]"})
        assert short.status_code == 422 and "one per frame" in _error(short)["message"]
        far = json.dumps([None, {"lat": 61.0, "lon": 25.0}])
        outside = client.post(f"/v1/maps/{map_id}/tracks", files=_frames(2), data={"wait_s": "0", "priors": far})
        assert outside.status_code == 422 and _error(outside)["code"] == "outside_map"
        assert _error(outside)["details"]["frame"] == 1

        assert table_counts(service.database) == before
        assert stored_files(service.data_dir) == files_before

        # Queries of another map are refused; a malformed JSON body too.
        photo = jpeg_bytes(320, 240, gps=INSIDE, seed=9)
        foreign = client.post(f"/v1/maps/{other_id}/queries", files={"image": ("q.jpg", photo)}, data={"wait_s": "0"})
        assert foreign.status_code == 202, foreign.text
        mine = client.post(f"/v1/maps/{map_id}/queries", files={"image": ("m.jpg", photo)}, data={"wait_s": "0"})
        body = {"query_ids": [mine.json()["id"], foreign.json()["id"]], "wait_s": 0}
        refused = client.post(f"/v1/maps/{map_id}/tracks", json=body)
        assert refused.status_code == 422, refused.text
        err = _error(refused)
        assert err["code"] == "foreign_query" and err["details"] == {"frame": 1, "query_id": foreign.json()["id"]}
        malformed = client.post(f"/v1/maps/{map_id}/tracks", json={"query_ids": "all"})
        assert malformed.status_code == 422 and "query_ids" in _error(malformed)["message"]
        missing = client.post(f"/v1/maps/{map_id}/tracks", json={"query_ids": [987654]})
        assert missing.status_code == 404 and "987654" in _error(missing)["message"]
        assert client.get("/v1/tracks/987654").status_code == 404


def test_a_track_stores_one_job_and_a_query_per_frame(service: RunningProcess) -> None:
    with service.client() as client:
        map_id = _map(client)
        priors = json.dumps([{"heading_deg": 90.0}, None, {"lat": INSIDE[0], "lon": INSIDE[1], "radius_m": 20}])
        created = client.post(f"/v1/maps/{map_id}/tracks", files=_frames(3), data={"wait_s": "0.2", "priors": priors})
        assert created.status_code == 202, created.text
        track = created.json()
        assert track["status"] == "queued" and [f["index"] for f in track["frames"]] == [0, 1, 2]
        assert [f["original_filename"] for f in track["frames"]] == ["f0.jpg", "f1.jpg", "f2.jpg"]
        assert all(f["lat"] is None for f in track["frames"])
        jobs = read_rows(service.database, "SELECT kind, payload FROM jobs WHERE id = ?", (track["job_id"],))
        assert jobs[0]["kind"] == "locate_track" and json.loads(jobs[0]["payload"])["track_id"] == track["id"]
        params = [client.get(f"/v1/queries/{f['query_id']}").json() for f in track["frames"]]
        assert all(q["job_id"] == track["job_id"] and q["status"] == "queued" for q in params)
        params = [q["params"] for q in params]
        assert params[0]["prior_heading_deg"] == 90.0 and params[0]["prior"]["source"] == "exif"
        assert params[1]["prior"]["source"] == "exif" and params[1].get("prior_heading_deg") is None
        assert params[2]["prior"] == {**params[2]["prior"], "source": "request", "radius_m": 20.0}
        geojson = client.get(f"/v1/tracks/{track['id']}", params={"format": "geojson"})
        assert geojson.headers["content-type"].startswith("application/geo+json")
        assert geojson.json()["features"] == [] and geojson.json()["status"] == "queued"

        frame_delete = client.delete(f"/v1/queries/{track['frames'][0]['query_id']}")
        assert frame_delete.status_code == 409 and _error(frame_delete)["details"] == {"track_id": track["id"]}
        files_before = stored_files(service.data_dir)
        assert client.delete(f"/v1/tracks/{track['id']}").status_code == 204
        assert client.get(f"/v1/tracks/{track['id']}").status_code == 404
        for frame in track["frames"]:
            assert client.get(f"/v1/queries/{frame['query_id']}").status_code == 404
        assert len(stored_files(service.data_dir)) == len(files_before) - 3


def test_the_frames_can_be_ordered_by_capture_time(service: RunningProcess, tmp_path: Path) -> None:
    from PIL import Image

    photos = []
    for i, stamp in enumerate(("2024:05:01 10:00:09", "2024:05:01 10:00:01", "2024:05:01 10:00:05")):
        path = tmp_path / f"t{i}.jpg"
        path.write_bytes(jpeg_bytes(320, 240, gps=INSIDE, seed=20 + i))
        image = Image.open(path)
        exif = image.getexif()
        exif.get_ifd(0x8769)[0x9003] = stamp  # DateTimeOriginal
        image.save(path, exif=exif, quality=90)
        photos.append(("images", (path.name, path.read_bytes(), "image/jpeg")))
    with service.client() as client:
        map_id = _map(client)
        data = {"wait_s": "0", "by_capture_time": "true"}
        track = client.post(f"/v1/maps/{map_id}/tracks", files=photos, data=data).json()
        assert [f["original_filename"] for f in track["frames"]] == ["t1.jpg", "t2.jpg", "t0.jpg"], track
        assert track["params"]["order"] == "capture_time"
        assert [f["capture_time"] for f in track["frames"]] == sorted(f["capture_time"] for f in track["frames"])
