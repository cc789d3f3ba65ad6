"""Maps as jobs (issue 22) against a real ``geoloc serve`` on loopback, on both profiles.

``POST /v1/maps`` answers 202 and the workers parse the file; the map is usable once ``done``. A gzip that
inflates to 3 GB is refused with 413 in the POST itself within seconds and nothing is stored; a broken file
fails with a clear message that names no server path; a map not done is refused (409) for photos; a map
deleted while queued leaves nothing; reads keep answering while a parse runs.
"""

from __future__ import annotations

import io
import random
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.settings import shared_path
from tests.bombs import gzip_bomb
from tests.conftest import Profile
from tests.service_fixtures import (
    WRITE_KEY,
    RunningProcess,
    jpeg_bytes,
    running_service,
    stored_files,
    table_counts,
    wait_for,
)

pytestmark = pytest.mark.slow

DECOMPRESSED_LIMIT = 1024 * 1024 * 1024
"""The default GEOLOC_MAX_DECOMPRESSED_BYTES, stated so that the test holds if the default changes."""
HELSINKI = shared_path("data", "osm", "helsinki.osm.pbf")


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[RunningProcess]:
    """A service whose one worker parses maps (and claims nothing else)."""
    with running_service(
        tmp_path_factory.mktemp("mapjobs") / "data",
        workers=0,
        GEOLOC_MAX_DECOMPRESSED_BYTES=str(DECOMPRESSED_LIMIT),
        **profile.new_env(),
    ) as running:
        yield running


@pytest.fixture(scope="module")
def client(service: RunningProcess) -> Iterator[httpx.Client]:
    with service.client(WRITE_KEY, timeout=120.0) as c:
        yield c


def _paths_in(text: str, service: RunningProcess) -> list[str]:
    """Server paths that ``text`` shows (the data folder, temp folders, GDAL's virtual paths)."""
    return [p for p in (str(service.data_dir), "/tmp", "/vsizip", "upload-", ".part") if p in text]


def test_a_map_is_202_then_done_with_its_progress(client: httpx.Client) -> None:
    response = client.post("/v1/maps", files={"file": (HELSINKI.name, HELSINKI.read_bytes())}, data={"name": "h"})
    assert response.status_code == 202, response.text
    queued = response.json()
    assert queued["status"] in ("queued", "processing") and queued["job_id"] is not None
    assert queued["building_count"] == 0 and queued["source_format"] == "pbf"
    done = wait_for(
        lambda: (m := client.get(f"/v1/maps/{queued['id']}").json())["status"] == "done" and m,
        timeout=120,
        what="the map's parse",
    )
    assert done["building_count"] > 100 and done["facade_count"] > done["building_count"]
    assert done["progress"]["buildings"] == done["building_count"] and done["error"] is None
    assert 60.1 < done["bbox"]["min_lat"] < done["bbox"]["max_lat"] < 60.3
    buildings = client.get(f"/v1/maps/{queued['id']}/buildings").json()["features"]
    assert len(buildings) == done["building_count"]
    job = client.get(f"/v1/jobs/{queued['job_id']}").json()
    assert job["status"] == "done" and job["kind"] == "load_map"
    again = client.post("/v1/maps", files={"file": ("copy.pbf", HELSINKI.read_bytes())}, data={"name": "again"})
    assert again.status_code == 200 and again.json()["duplicate"] and again.json()["id"] == queued["id"]


def test_gzip_bombs_are_413_within_seconds_and_nothing_is_stored(service: RunningProcess, client: httpx.Client) -> None:
    bomb = gzip_bomb(3 * 1024**3)  # 3 GiB of spaces after an OSM XML head, a few MB sent
    assert len(bomb) < 8 * 1024 * 1024
    before = (table_counts(service.database), stored_files(service.data_dir))
    answers: list[tuple[int, float, dict[str, Any]]] = []

    def upload(i: int) -> None:
        with service.client(WRITE_KEY, timeout=60.0) as own:
            start = time.monotonic()
            response = own.post("/v1/maps", files={"file": (f"city{i}.osm.gz", bomb)}, data={"name": f"bomb {i}"})
            answers.append((response.status_code, time.monotonic() - start, response.json()))

    threads = [threading.Thread(target=upload, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    read_s = []
    while any(thread.is_alive() for thread in threads):  # reads keep being answered meanwhile
        start = time.monotonic()
        assert client.get("/v1/maps").status_code == 200
        read_s.append(time.monotonic() - start)
        time.sleep(0.05)
    for thread in threads:
        thread.join()
    assert [status for status, _, _ in answers] == [413, 413], answers
    for _, seconds, body in answers:
        assert seconds < 5.0, f"413 after {seconds:.1f} s"
        assert body["error"]["code"] == "payload_too_large"
        assert body["error"]["details"] == {"limit_bytes": DECOMPRESSED_LIMIT, "max_ratio": 500}
        assert body["error"]["message"].endswith("decompresses to more than 500 times its size (a decompression bomb)")
        assert not _paths_in(body["error"]["message"], service)
    assert read_s and max(read_s) < 1.0, f"slowest read {max(read_s):.2f} s during the bombs"
    assert (table_counts(service.database), stored_files(service.data_dir)) == before


def _broken_shapefile_zip() -> bytes:
    """A zip with a .shp that is not one, and no .shx: GDAL's message names its /vsizip/ path."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("roads/buildings.shp", b"\x00\x00\x27\x0a" + b"not a shapefile" * 20)
        archive.writestr("roads/buildings.dbf", b"junk")
    return buffer.getvalue()


def test_a_broken_zipped_shapefile_fails_clearly_without_a_server_path(
    service: RunningProcess, client: httpx.Client
) -> None:
    content = _broken_shapefile_zip()
    before = table_counts(service.database)
    waited = client.post("/v1/maps", files={"file": ("city.zip", content)}, data={"name": "c", "wait_s": "60"})
    assert waited.status_code == 422, waited.text
    message = waited.json()["error"]["message"]
    assert message.startswith("city.zip: cannot read the zipped Shapefile") and not _paths_in(message, service)
    assert table_counts(service.database) == before  # answered in the POST: the failed map is not kept
    queued = client.post("/v1/maps", files={"file": ("city.zip", content)}, data={"name": "c"})
    assert queued.status_code == 202
    failed = wait_for(
        lambda: (m := client.get(f"/v1/maps/{queued.json()['id']}").json())["status"] == "failed" and m,
        timeout=60,
        what="the map to fail",
    )
    assert failed["error"].startswith("city.zip: cannot read the zipped Shapefile")
    assert not _paths_in(failed["error"], service)
    photo = client.post(f"/v1/maps/{failed['id']}/references", files={"image": ("r.jpg", jpeg_bytes())})
    assert photo.status_code == 409 and photo.json()["error"]["code"] == "map_not_ready"
    assert "failed to load" in photo.json()["error"]["message"]
    assert client.delete(f"/v1/maps/{failed['id']}").status_code == 204


def test_reads_keep_answering_while_a_map_parses(service: RunningProcess, client: httpx.Client) -> None:
    content = HELSINKI.read_bytes() + b""  # the same file read with other options is another map: a new parse
    response = client.post(
        "/v1/maps", files={"file": (HELSINKI.name, content)}, data={"name": "h2", "name_attribute": "name:fi"}
    )
    assert response.status_code == 202
    map_id = response.json()["id"]
    read_s = []
    while (m := client.get(f"/v1/maps/{map_id}").json())["status"] != "done":
        assert m["status"] in ("queued", "processing"), m
        start = time.monotonic()
        assert client.get("/v1/maps").status_code == 200
        read_s.append(time.monotonic() - start)
        time.sleep(0.05)
    assert max(read_s, default=0.0) < 1.0


@pytest.fixture(scope="module")
def stalled(tmp_path_factory: pytest.TempPathFactory, built_models: Path, profile: Profile) -> Iterator[RunningProcess]:
    """A service whose worker claims no map jobs (only the tests' ``test_record``): uploaded maps stay queued."""
    with running_service(
        tmp_path_factory.mktemp("mapjobs-stalled") / "data",
        workers=1,
        models=built_models,
        GEOLOC_WORKER_KINDS="test_record",
        **profile.new_env(),
    ) as running:
        yield running


def test_a_queued_map_refuses_photos_and_can_be_deleted(stalled: RunningProcess) -> None:
    with stalled.client(WRITE_KEY) as client:
        before = (table_counts(stalled.database), stored_files(stalled.data_dir))
        response = client.post("/v1/maps", files={"file": ("h.pbf", HELSINKI.read_bytes())}, data={"name": "h"})
        assert response.status_code == 202
        queued = response.json()
        map_id = queued["id"]
        assert client.get(f"/v1/maps/{map_id}").json()["status"] == "queued"
        for url, field in ((f"/v1/maps/{map_id}/references", "image"), (f"/v1/maps/{map_id}/queries", "image")):
            refused = client.post(url, files={field: ("p.jpg", jpeg_bytes())})
            assert refused.status_code == 409, refused.text
            assert refused.json()["error"]["code"] == "map_not_ready"
            assert f"GET /v1/maps/{map_id}" in refused.json()["error"]["message"]
        assert client.get(f"/v1/maps/{map_id}/buildings").status_code == 409
        assert client.get(f"/v1/maps/{map_id}/streets").status_code == 409
        assert client.delete(f"/v1/maps/{map_id}").status_code == 204  # its queued job cancelled, then deleted
        assert client.get(f"/v1/jobs/{queued['job_id']}").status_code == 404
        assert (table_counts(stalled.database), stored_files(stalled.data_dir)) == before


def test_the_decompressed_size_limit_counts_a_zip_s_members_together(tmp_path: Path, profile: Profile) -> None:
    env = {"GEOLOC_MAX_DECOMPRESSED_BYTES": "10000000", **profile.new_env()}
    with running_service(tmp_path / "data", workers=0, **env) as limited, limited.client() as client:
        zipped = io.BytesIO()
        with zipfile.ZipFile(zipped, "w", zipfile.ZIP_STORED) as archive:
            for name in ("a.shp", "a.dbf", "a.shx"):  # 4 MiB each: over the limit only together
                archive.writestr(name, random.Random(name).randbytes(4 * 1024 * 1024))
        response = client.post("/v1/maps", files={"file": ("a.zip", zipped.getvalue())}, data={"name": "z"})
        assert response.status_code == 413 and response.json()["error"]["code"] == "payload_too_large"
        assert response.json()["error"]["message"] == "a.zip: decompresses to more than the limit of 10000000 bytes"
