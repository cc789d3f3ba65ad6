"""``geoloc ingest`` against a real ``geoloc serve`` on loopback (API only, ``--workers 0``).

The 29 real Lund photos rejected as outside the Helsinki map, a mixed folder (photos, non-images, a
duplicate) and a second run that creates nothing; an unknown map, bad keys and an unreachable service;
photos without GPS placed by a GPX track (``--gpx``); a panorama refused as a reference and as a query.
Retries against a mock transport are in ``tests/unit/cli/test_ingest_retries.py``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import subprocess
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from contracts.settings import shared_path
from geoloc.photos.exif import ExifFields, write_jpeg
from tests.conftest import Profile
from tests.service_fixtures import (
    READ_KEY,
    REPO_ROOT,
    WRITE_KEY,
    RunningProcess,
    free_port,
    geoloc_command,
    panorama_jpeg_bytes,
    read_rows,
    running_service,
    stored_files,
    table_counts,
)
from tests.unit.cli.test_ingest_geotag import write_gpx
from tests.unit.cli.test_ingest_retries import INSIDE_HELSINKI, photo

pytestmark = pytest.mark.slow  # a real server (tests/e2e/ is the slow suite)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[RunningProcess]:
    with running_service(tmp_path_factory.mktemp("ingest") / "data", workers=0, **profile.new_env()) as running:
        yield running


@pytest.fixture(scope="module")
def helsinki_id(service: RunningProcess) -> int:
    with service.client(WRITE_KEY) as client, shared_path("data", "osm", "helsinki.osm.pbf").open("rb") as f:
        response = client.post(
            "/v1/maps", files={"file": ("helsinki.osm.pbf", f)}, data={"wait_s": "120", "name": "helsinki"}
        )
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


def run_ingest(service: RunningProcess, *args: str, api_key: str = WRITE_KEY) -> subprocess.CompletedProcess[str]:
    """``geoloc ingest ARGS --url ... --api-key ...`` as a user would run it."""
    return subprocess.run(
        [*geoloc_command(), "ingest", *args, "--url", str(service.base_url), "--api-key", api_key],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "200"},
        check=False,
    )


def outcomes(report: dict[str, Any]) -> dict[str, str]:
    return {f["path"]: f["outcome"] for f in report["files"]}


def test_lund_photos_are_all_rejected_as_outside_the_map(
    service: RunningProcess, helsinki_id: int, tmp_path: Path
) -> None:
    lund = shared_path("data", "lund", "images")
    before = table_counts(service.database)
    out = tmp_path / "lund.json"
    result = run_ingest(service, str(lund), "--map", str(helsinki_id), "--json", str(out))
    assert result.returncode == 0, result.stdout + result.stderr  # rejections are not failures
    report = json.loads(out.read_text())
    assert report["summary"] == {"accepted": 0, "present": 0, "duplicate": 0, "rejected": 29, "skipped": 0, "failed": 0}
    truth = {row["name"]: row for row in csv.DictReader(shared_path("data", "lund", "gps.csv").open())}
    assert len(report["files"]) == len(truth) == 29
    for f in report["files"]:
        assert (f["http_status"], f["error_code"]) == (422, "outside_map"), f
        assert "m outside map" in f["reason"] and "from exif" in f["reason"], f  # EXIF GPS read, distance given
        assert abs(f["details"]["lat"] - float(truth[f["path"]]["lat"])) < 1e-5
        assert abs(f["details"]["lon"] - float(truth[f["path"]]["lon"])) < 1e-5
        assert 800_000 < f["details"]["distance_m"] < 840_000  # Lund is ~818 km from central Helsinki
    assert "rejected by the service" in result.stdout and "422 outside_map" in result.stdout
    assert "29 photo(s) were rejected" in result.stdout and "exit code 0" in result.stdout
    assert table_counts(service.database) == before, "nothing stored"


def _png(size: int = 120) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (size, size), (80, 120, 160)).save(buffer, "PNG")
    return buffer.getvalue()


def test_mixed_folder_then_a_second_run_creates_nothing(
    service: RunningProcess, helsinki_id: int, tmp_path: Path
) -> None:
    folder = tmp_path / "photos"
    (folder / "sub").mkdir(parents=True)
    photo(folder / "a.jpg", INSIDE_HELSINKI[0], seed=1)
    photo(folder / "b.jpg", INSIDE_HELSINKI[1], seed=2)
    shutil.copy(folder / "a.jpg", folder / "copy-of-a.jpg")  # same content: uploaded once
    photo(folder / "sub" / "c.jpg", INSIDE_HELSINKI[2], seed=3)  # only with --recursive
    (folder / "no-gps.png").write_bytes(_png())  # a photo the service refuses: no position
    (folder / "notes.txt").write_text("not a photo")
    (folder / "fake.jpg").write_bytes(b"a text file named like a photo")
    (folder / "empty.jpg").write_bytes(b"")
    refs_before = len(read_rows(service.database, "SELECT id FROM reference_images WHERE map_id = ?", (helsinki_id,)))

    first = run_ingest(service, str(folder), "--map", str(helsinki_id), "--json", str(tmp_path / "1.json"))
    assert first.returncode == 0, first.stdout + first.stderr
    report = json.loads((tmp_path / "1.json").read_text())
    assert outcomes(report) == {
        "a.jpg": "accepted",
        "copy-of-a.jpg": "duplicate",
        "b.jpg": "accepted",
        "no-gps.png": "rejected",
        "notes.txt": "skipped",
        "fake.jpg": "skipped",
        "empty.jpg": "skipped",
    }
    by_path = {f["path"]: f for f in report["files"]}
    assert by_path["copy-of-a.jpg"]["duplicate_of"] == "a.jpg"
    assert by_path["no-gps.png"]["error_code"] == "no_position" and "422" in by_path["no-gps.png"]["reason"]
    assert "not a photo" in by_path["fake.jpg"]["reason"] and by_path["empty.jpg"]["reason"] == "empty file"
    assert all(by_path[p]["reference_id"] and by_path[p]["job_id"] for p in ("a.jpg", "b.jpg"))
    refs = read_rows(service.database, "SELECT id, sha256 FROM reference_images WHERE map_id = ?", (helsinki_id,))
    assert len(refs) == refs_before + 2
    assert {by_path["a.jpg"]["sha256"], by_path["b.jpg"]["sha256"]} <= {r["sha256"] for r in refs}
    counts = table_counts(service.database)

    second = run_ingest(service, str(folder), "--map", str(helsinki_id), "--json", str(tmp_path / "2.json"))
    assert second.returncode == 0, second.stdout + second.stderr
    again = json.loads((tmp_path / "2.json").read_text())
    assert again["summary"] == {"accepted": 0, "present": 2, "duplicate": 1, "rejected": 1, "skipped": 3, "failed": 0}
    assert {f["path"]: f["reference_id"] for f in again["files"] if f["outcome"] == "present"} == {
        "a.jpg": by_path["a.jpg"]["reference_id"],
        "b.jpg": by_path["b.jpg"]["reference_id"],
    }
    assert "already present" in second.stdout
    assert table_counts(service.database) == counts, "the second run created no rows"

    third = run_ingest(
        service, str(folder), "--map", str(helsinki_id), "--recursive", "--json", str(tmp_path / "3.json")
    )
    assert third.returncode == 0, third.stdout + third.stderr
    recursive = outcomes(json.loads((tmp_path / "3.json").read_text()))
    assert recursive["sub/c.jpg"] == "accepted" and recursive["a.jpg"] == recursive["b.jpg"] == "present"


def test_cannot_start_exits_2_with_the_reason(service: RunningProcess, helsinki_id: int, tmp_path: Path) -> None:
    photo(tmp_path / "x.jpg", INSIDE_HELSINKI[0], seed=6)
    counts = table_counts(service.database)
    unknown_map = run_ingest(service, str(tmp_path), "--map", "424242")
    assert unknown_map.returncode == 2 and "map 424242 not found" in unknown_map.stderr
    bad_key = run_ingest(service, str(tmp_path), "--map", str(helsinki_id), api_key="not-a-key")
    assert bad_key.returncode == 2 and "invalid API key" in bad_key.stderr
    read_only = run_ingest(service, str(tmp_path), "--map", str(helsinki_id), api_key=READ_KEY)
    assert read_only.returncode == 1, read_only.stderr  # a key without the write scope is a failure, not a rejection
    assert "403 forbidden" in read_only.stdout and "failed after retries" in read_only.stdout
    assert table_counts(service.database) == counts
    nobody = subprocess.run(
        [*geoloc_command(), "ingest", str(tmp_path), "--map", "1", "--url", f"http://127.0.0.1:{free_port()}"]
        + ["--retries", "1"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert nobody.returncode == 2 and "cannot reach the service" in nobody.stderr


def test_a_gpx_track_places_photos_without_gps_and_skips_one_outside_it(
    service: RunningProcess, helsinki_id: int, tmp_path: Path
) -> None:
    """A camera without GPS or compass, set to UTC+2, walking north in Helsinki with a logger."""
    start = datetime(2024, 6, 1, 9, 0, 0, tzinfo=UTC)
    lat0, lon0 = INSIDE_HELSINKI[0]
    track = [(start + timedelta(seconds=2 * i), lat0 + i * 1.5 / 111_132.0, lon0) for i in range(30)]
    gpx = write_gpx(tmp_path / "walk.gpx", track)
    folder = tmp_path / "camera"
    folder.mkdir()
    rgb = np.random.default_rng(21).integers(0, 255, size=(240, 320, 3), dtype=np.uint8)
    for name, seconds in (("a.jpg", 10), ("b.jpg", 31), ("late.jpg", 600)):
        local = (start + timedelta(hours=2, seconds=seconds)).replace(tzinfo=None)
        write_jpeg(folder / name, rgb + seconds % 7, ExifFields(focal_35mm=28, taken=local))
    out = tmp_path / "gpx.json"
    result = run_ingest(
        service, str(folder), "--map", str(helsinki_id), "--gpx", str(gpx), "--time-offset", "-7200", "--json", str(out)
    )
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads(out.read_text())
    assert outcomes(report) == {"a.jpg": "accepted", "b.jpg": "accepted", "late.jpg": "skipped"}
    by_path = {f["path"]: f for f in report["files"]}
    assert "after the GPX track ends" in by_path["late.jpg"]["reason"] and by_path["late.jpg"]["reference_id"] is None
    assert "after the GPX track ends" in result.stdout
    for name, seconds in (("a.jpg", 10), ("b.jpg", 31)):
        (row,) = read_rows(
            service.database,
            "SELECT gps_lat, gps_lon, position_source, prior_heading_deg FROM reference_images WHERE id = ?",
            (by_path[name]["reference_id"],),
        )
        north_m = (row["gps_lat"] - (lat0 + seconds / 2 * 1.5 / 111_132.0)) * 111_132.0
        east_m = (row["gps_lon"] - lon0) * 111_320.0 * math.cos(math.radians(lat0))
        assert math.hypot(north_m, east_m) < 1.0 and row["position_source"] == "request", row
        assert abs((row["prior_heading_deg"] + 180.0) % 360.0 - 180.0) < 0.1, "the direction of travel: north"


def test_a_panorama_is_refused_as_a_reference_and_as_a_query_and_nothing_is_stored(
    service: RunningProcess, helsinki_id: int, tmp_path: Path
) -> None:
    data = panorama_jpeg_bytes(gps=INSIDE_HELSINKI[0])  # 2:1 with GPano:ProjectionType="equirectangular"
    folder = tmp_path / "sphere"
    folder.mkdir()
    (folder / "sphere.jpg").write_bytes(data)
    counts, files = table_counts(service.database), stored_files(service.data_dir)
    out = tmp_path / "sphere.json"
    result = run_ingest(service, str(folder), "--map", str(helsinki_id), "--json", str(out))
    assert result.returncode == 0, result.stdout + result.stderr  # a rejection, not a failure
    (only,) = json.loads(out.read_text())["files"]
    assert (only["outcome"], only["http_status"], only["error_code"]) == ("rejected", 422, "unsupported_projection")
    assert "equirectangular panorama" in only["reason"] and "perspective photos" in only["reason"]
    assert "422 unsupported_projection" in result.stdout
    with service.client(READ_KEY) as client:
        answer = client.post(
            f"/v1/maps/{helsinki_id}/queries", files={"image": ("sphere.jpg", data)}, data={"wait_s": "0"}
        )
    assert answer.status_code == 422, answer.text
    error = answer.json()["error"]
    assert error["code"] == "unsupported_projection" and "equirectangular" in error["message"]
    assert error["details"]["supported"] == ["perspective"]
    assert str(service.data_dir) not in answer.text and "Traceback" not in answer.text, "no server path or stack"
    assert table_counts(service.database) == counts, "no reference or query row"
    assert stored_files(service.data_dir) == files, "no file stored or left behind"
