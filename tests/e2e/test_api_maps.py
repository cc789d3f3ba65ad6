"""The REST API against a real ``geoloc serve`` (uvicorn + a worker process) on loopback.

With a real SQLite file: maps (the real Helsinki extract), references, jobs, auth, and every bad input
answered with the right 4xx, a reason, the service still up and nothing stored.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from PIL import Image

from contracts.settings import shared_path
from tests.conftest import Profile
from tests.service_fixtures import (
    READ_KEY,
    REPO_ROOT,
    WRITE_KEY,
    RunningProcess,
    geoloc_command,
    jpeg_bytes,
    png_header_only,
    read_rows,
    running_service,
    service_env,
    stored_files,
    table_counts,
    wait_for,
)

pytestmark = pytest.mark.slow

MAX_MAP_BYTES = 4_000_000
MAX_IMAGE_BYTES = 2_000_000
MAX_IMAGE_PIXELS = 4_000_000
INSIDE_HELSINKI = (60.1716, 24.9443)
LUND = (55.7047, 13.1910)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, built_models: Path, profile: Profile) -> Iterator[RunningProcess]:
    with running_service(
        tmp_path_factory.mktemp("api") / "data",
        workers=1,
        models=built_models,
        **profile.new_env(),
        GEOLOC_MAX_MAP_BYTES=str(MAX_MAP_BYTES),
        GEOLOC_MAX_IMAGE_BYTES=str(MAX_IMAGE_BYTES),
        GEOLOC_MAX_IMAGE_PIXELS=str(MAX_IMAGE_PIXELS),
    ) as running:
        yield running


@pytest.fixture(scope="module")
def client(service: RunningProcess) -> Iterator[httpx.Client]:
    with service.client(WRITE_KEY) as c:
        yield c


@pytest.fixture(scope="module")
def helsinki(client: httpx.Client) -> dict[str, Any]:
    path = shared_path("data", "osm", "helsinki.osm.pbf")
    with path.open("rb") as f:
        response = client.post(
            "/v1/maps", files={"file": ("helsinki.osm.pbf", f)}, data={"wait_s": "120", "name": "helsinki"}
        )
    assert response.status_code == 201, response.text
    return response.json()


def error_of(response: httpx.Response) -> dict[str, Any]:
    body = response.json()
    assert set(body) == {"error"} and {"code", "message"} <= set(body["error"]), body
    return body["error"]


class Unchanged:
    """Snapshot of row counts and stored files, compared after a rejected request."""

    def __init__(self, service: RunningProcess) -> None:
        self.service = service
        # Earlier tests' jobs (a reference labelled, then deleted) may still be writing, e.g. the map's
        # vocabulary on its first label job: wait until none is queued or running before taking the snapshot.
        wait_for(
            lambda: not read_rows(service.database, "SELECT id FROM jobs WHERE status IN ('queued', 'running')"),
            timeout=120,
            what="earlier tests' jobs to finish",
        )
        self.counts = table_counts(service.database)
        self.files = stored_files(service.data_dir)

    def check(self) -> None:
        assert httpx.get(f"{self.service.base_url}/healthz", timeout=5).status_code == 200, "service still answers"
        assert table_counts(self.service.database) == self.counts, "database unchanged"
        assert stored_files(self.service.data_dir) == self.files, "no file stored or left behind"


# --- system and maps ----------------------------------------------------------------------------


def test_health_and_readiness(service: RunningProcess, client: httpx.Client) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = wait_for(lambda: (r := client.get("/readyz")).status_code == 200 and r, timeout=30, what="readiness")
    body = ready.json()
    assert body["status"] == "ready" and body["live_workers"] >= 1
    assert body["schema_version"] == body["expected_schema_version"]


def test_helsinki_map_upload(helsinki: dict[str, Any]) -> None:
    assert helsinki["source_format"] == "pbf" and helsinki["name"] == "helsinki"
    assert helsinki["building_count"] > 300 and helsinki["facade_count"] > helsinki["building_count"]
    bbox = helsinki["bbox"]
    assert bbox["min_lat"] < INSIDE_HELSINKI[0] < bbox["max_lat"]
    assert bbox["min_lon"] < INSIDE_HELSINKI[1] < bbox["max_lon"]
    assert helsinki["repair_report"]["format"] == "pbf"
    assert not helsinki["duplicate"]


def test_map_reads(client: httpx.Client, helsinki: dict[str, Any], service: RunningProcess) -> None:
    map_id = helsinki["id"]
    assert client.get(f"/v1/maps/{map_id}").json()["building_count"] == helsinki["building_count"]
    assert map_id in [m["id"] for m in client.get("/v1/maps").json()["maps"]]
    response = client.get(f"/v1/maps/{map_id}/buildings")
    assert response.status_code == 200 and response.headers["content-type"].startswith("application/geo+json")
    collection = response.json()
    assert collection["type"] == "FeatureCollection"
    assert len(collection["features"]) == helsinki["building_count"]
    feature = collection["features"][0]
    lon, lat = feature["geometry"]["coordinates"][0][0]
    assert helsinki["bbox"]["min_lat"] <= lat <= helsinki["bbox"]["max_lat"]
    assert helsinki["bbox"]["min_lon"] <= lon <= helsinki["bbox"]["max_lon"]
    assert {"building_id", "osm_id", "name", "height_m"} <= set(feature["properties"])
    assert any(f["properties"]["name"] for f in collection["features"])
    assert (service.data_dir / "maps").is_dir()


def test_same_map_file_again_returns_the_existing_map(client: httpx.Client, helsinki: dict[str, Any]) -> None:
    with shared_path("data", "osm", "helsinki.osm.pbf").open("rb") as f:
        response = client.post("/v1/maps", files={"file": ("copy.pbf", f)}, data={"wait_s": "120", "name": "again"})
    assert response.status_code == 200
    assert response.json()["id"] == helsinki["id"] and response.json()["duplicate"] is True


GEOJSON_MAP = (
    b'{"type": "FeatureCollection", "features": [{"type": "Feature", "id": "b1", '
    b'"properties": {"building": "yes", "name": "Test hall"}, "geometry": {"type": "Polygon", '
    b'"coordinates": [[[24.0, 60.0], [24.001, 60.0], [24.001, 60.0005], [24.0, 60.0005], [24.0, 60.0]]]}}]}'
)


def test_geojson_map_upload_and_delete(client: httpx.Client, service: RunningProcess) -> None:
    before = Unchanged(service)
    response = client.post(
        "/v1/maps", files={"file": ("town.json", GEOJSON_MAP)}, data={"wait_s": "120", "name": "town"}
    )
    assert response.status_code == 201, response.text
    created = response.json()
    assert created["source_format"] == "geojson" and created["building_count"] == 1
    features = client.get(f"/v1/maps/{created['id']}/buildings").json()["features"]
    assert features[0]["properties"]["name"] == "Test hall"
    assert client.delete(f"/v1/maps/{created['id']}").status_code == 204
    assert error_of(client.get(f"/v1/maps/{created['id']}"))["code"] == "not_found"
    assert client.delete(f"/v1/maps/{created['id']}").status_code == 404
    before.check()


# --- references ---------------------------------------------------------------------------------


def test_reference_with_exif_gps_is_accepted_then_deleted(
    client: httpx.Client, helsinki: dict[str, Any], service: RunningProcess
) -> None:
    before = Unchanged(service)
    photo = jpeg_bytes(gps=INSIDE_HELSINKI, seed=1)
    response = client.post(f"/v1/maps/{helsinki['id']}/references", files={"image": ("IMG_1.jpg", photo)})
    assert response.status_code == 202, response.text
    accepted = response.json()
    assert accepted["status"] == "queued" and accepted["job_id"] and not accepted["duplicate"]
    reference = client.get(f"/v1/references/{accepted['id']}").json()
    assert reference["position"]["source"] == "exif"
    assert abs(reference["position"]["lat"] - INSIDE_HELSINKI[0]) < 1e-5
    assert abs(reference["position"]["lon"] - INSIDE_HELSINKI[1]) < 1e-5
    assert (reference["width"], reference["height"]) == (640, 480)
    assert reference["focal_length_35mm"] == 28
    assert reference["status"] in ("queued", "processing", "done", "failed")
    job = client.get(f"/v1/jobs/{accepted['job_id']}").json()
    assert job["kind"] == "label_reference"
    assert job["payload"] == {"reference_id": accepted["id"], "map_id": helsinki["id"]}
    assert len(stored_files(service.data_dir)) == len(before.files) + 1

    again = client.post(f"/v1/maps/{helsinki['id']}/references", files={"image": ("copy.jpg", photo)})
    assert again.status_code == 200 and again.json()["duplicate"] is True and again.json()["id"] == accepted["id"]

    assert client.delete(f"/v1/references/{accepted['id']}").status_code == 204
    assert client.get(f"/v1/references/{accepted['id']}").status_code == 404
    assert stored_files(service.data_dir) == before.files
    counts = table_counts(service.database)
    assert counts["reference_images"] == before.counts["reference_images"]


def test_reference_position_from_the_request_overrides_exif(client: httpx.Client, helsinki: dict[str, Any]) -> None:
    photo = jpeg_bytes(gps=LUND, seed=2)  # EXIF says Lund; the client knows better
    response = client.post(
        f"/v1/maps/{helsinki['id']}/references",
        files={"image": ("x.jpg", photo)},
        data={"lat": str(INSIDE_HELSINKI[0]), "lon": str(INSIDE_HELSINKI[1]), "heading_deg": "90"},
    )
    assert response.status_code == 202, response.text
    reference = client.get(f"/v1/references/{response.json()['id']}").json()
    assert reference["position"]["source"] == "request" and reference["prior_heading_deg"] == 90
    assert client.delete(f"/v1/references/{reference['id']}").status_code == 204


def test_a_mapillary_compass_is_the_prior_with_its_accuracy_and_a_form_heading_overrides_it(
    client: httpx.Client, helsinki: dict[str, Any]
) -> None:
    description = json.dumps({"MAPCompassHeading": {"TrueHeading": 123.5, "AccuracyDegrees": 20.0}})
    # GPSImgDirection "M" is there too: the Mapillary true heading wins (as geoloc.photos.capture says).
    compass = jpeg_bytes(gps=INSIDE_HELSINKI, seed=11, description=description, direction=(300.0, "M"))
    response = client.post(f"/v1/maps/{helsinki['id']}/references", files={"image": ("walk.jpg", compass)})
    assert response.status_code == 202, response.text
    reference = client.get(f"/v1/references/{response.json()['id']}").json()
    assert (reference["prior_heading_deg"], reference["prior_heading_accuracy_deg"]) == (123.5, 20.0)
    assert client.delete(f"/v1/references/{reference['id']}").status_code == 204

    stated = jpeg_bytes(gps=INSIDE_HELSINKI, seed=12, description=description)
    response = client.post(
        f"/v1/maps/{helsinki['id']}/references", files={"image": ("said.jpg", stated)}, data={"heading_deg": "80"}
    )
    assert response.status_code == 202, response.text
    reference = client.get(f"/v1/references/{response.json()['id']}").json()
    assert (reference["prior_heading_deg"], reference["prior_heading_accuracy_deg"]) == (80, None)
    assert client.delete(f"/v1/references/{reference['id']}").status_code == 204

    # A query stores the same prior in its parameters; a form heading overrides it there too.
    for data, expected in (({}, (123.5, 20.0)), ({"heading_deg": "80"}, (80, None))):
        response = client.post(
            f"/v1/maps/{helsinki['id']}/queries", files={"image": ("q.jpg", compass)}, data={"wait_s": "0", **data}
        )
        assert response.status_code in (200, 202), response.text
        params = response.json()["params"]
        assert (params["prior_heading_deg"], params["prior_heading_accuracy_deg"]) == expected
        assert client.delete(f"/v1/queries/{response.json()['id']}").status_code == 204


# --- bad inputs ---------------------------------------------------------------------------------


def _truncated_jpeg() -> bytes:
    data = jpeg_bytes(gps=INSIDE_HELSINKI, seed=3)
    return data[: len(data) // 2]


def _png(width: int, height: int) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (width, height), (90, 90, 90)).save(buffer, "PNG")
    return buffer.getvalue()


BROKEN_PBF = b"\x00\x00\x00\x0dOSMHeader" + os.urandom(2000)
OSM_WITHOUT_BUILDINGS = b"<?xml version='1.0'?><osm version='0.6'><node id='1' lat='60.1' lon='24.9'/></osm>"

# (case, target, files, form data, api key, status, error code, message fragment)
BAD_INPUTS: list[tuple[str, str, Any, dict[str, str], str | None, int, str, str]] = [
    ("map: not map data", "maps", lambda: {"file": ("x.osm", b"hello, world")}, {"name": "x", "wait_s": "60"},
     WRITE_KEY, 422, "invalid_map", "not map data"),
    ("map: broken pbf", "maps", lambda: {"file": ("x.osm.pbf", BROKEN_PBF)}, {"name": "x", "wait_s": "60"},
     WRITE_KEY, 422, "invalid_map", "x.osm.pbf"),
    ("map: xml without buildings", "maps", lambda: {"file": ("x.osm", OSM_WITHOUT_BUILDINGS)},
     {"name": "x", "wait_s": "60"},
     WRITE_KEY, 422, "invalid_map", "no buildings"),
    ("map: jpeg named .osm", "maps", lambda: {"file": ("x.osm", jpeg_bytes())}, {"name": "x", "wait_s": "60"},
     WRITE_KEY, 422, "invalid_map", "not map data"),
    ("map: empty file", "maps", lambda: {"file": ("x.osm", b"")}, {"name": "x", "wait_s": "60"},
     WRITE_KEY, 422, "empty_file", "empty"),
    ("map: no name", "maps", lambda: {"file": ("x.osm", b"<osm/>")}, {},
     WRITE_KEY, 422, "invalid_request", "name"),
    ("map: too large (declared)", "maps", lambda: {"file": ("big.osm", b"<" * (MAX_MAP_BYTES + 200_000))},
     {"name": "x"}, WRITE_KEY, 413, "payload_too_large", "limit"),
    ("map: too large (file)", "maps", lambda: {"file": ("big.osm", b"<" * (MAX_MAP_BYTES + 1000))},
     {"name": "x"}, WRITE_KEY, 413, "payload_too_large", str(MAX_MAP_BYTES)),
    ("map: no API key", "maps", lambda: {"file": ("x.osm", GEOJSON_MAP)}, {"name": "x", "wait_s": "60"},
     None, 401, "unauthorized", "X-API-Key"),
    ("map: wrong API key", "maps", lambda: {"file": ("x.osm", GEOJSON_MAP)}, {"name": "x", "wait_s": "60"},
     "not-a-key", 401, "unauthorized", "invalid API key"),
    ("map: read-only key", "maps", lambda: {"file": ("x.osm", GEOJSON_MAP)}, {"name": "x", "wait_s": "60"},
     READ_KEY, 403, "forbidden", "write"),
    ("ref: not an image", "refs", lambda: {"image": ("a.jpg", b"just some text, not pixels")}, {},
     WRITE_KEY, 415, "not_an_image", "not an image"),
    ("ref: truncated jpeg", "refs", lambda: {"image": ("a.jpg", _truncated_jpeg())}, {},
     WRITE_KEY, 422, "corrupt_image", "truncated"),
    ("ref: too many pixels", "refs", lambda: {"image": ("a.png", _png(2500, 2000))},
     {"lat": "60.1716", "lon": "24.9443"}, WRITE_KEY, 413, "too_many_pixels", "5000000 pixels"),
    ("ref: decompression bomb", "refs", lambda: {"image": ("bomb.png", png_header_only(100_000, 100_000))},
     {"lat": "60.1716", "lon": "24.9443"}, WRITE_KEY, 413, "too_many_pixels", "decompression bomb"),
    ("ref: tiny image", "refs", lambda: {"image": ("a.png", _png(20, 20))}, {"lat": "60.1716", "lon": "24.9443"},
     WRITE_KEY, 422, "image_too_small", "at least"),
    ("ref: no gps, no lat/lon", "refs", lambda: {"image": ("a.jpg", jpeg_bytes(seed=4))}, {},
     WRITE_KEY, 422, "no_position", "no position"),
    ("ref: only lat", "refs", lambda: {"image": ("a.jpg", jpeg_bytes(seed=4))}, {"lat": "60.17"},
     WRITE_KEY, 422, "invalid_request", "both lat and lon"),
    ("ref: latitude out of range", "refs", lambda: {"image": ("a.jpg", jpeg_bytes(seed=4))},
     {"lat": "91", "lon": "24.9"}, WRITE_KEY, 422, "invalid_request", "lat must be between"),
    ("ref: exif gps outside the map", "refs", lambda: {"image": ("lund.jpg", jpeg_bytes(gps=LUND, seed=5))}, {},
     WRITE_KEY, 422, "outside_map", "m outside map"),
    ("ref: lat/lon outside the map", "refs", lambda: {"image": ("a.jpg", jpeg_bytes(seed=6))},
     {"lat": "60.19", "lon": "24.9443"}, WRITE_KEY, 422, "outside_map", "outside map"),
    ("ref: bad heading", "refs", lambda: {"image": ("a.jpg", jpeg_bytes(seed=6))},
     {"lat": "60.1716", "lon": "24.9443", "heading_deg": "400"}, WRITE_KEY, 422, "invalid_request", "heading_deg"),
    ("ref: too large", "refs", lambda: {"image": ("big.jpg", b"\xff\xd8" + os.urandom(MAX_IMAGE_BYTES))}, {},
     WRITE_KEY, 413, "payload_too_large", "limit"),
    ("ref: missing image field", "refs", lambda: {"photo": ("a.jpg", jpeg_bytes(seed=7))}, {},
     WRITE_KEY, 422, "invalid_request", "image"),
    ("ref: unknown map", "refs-unknown-map", lambda: {"image": ("a.jpg", jpeg_bytes(gps=INSIDE_HELSINKI))}, {},
     WRITE_KEY, 404, "not_found", "map 999999 not found"),
    ("ref: wrong API key", "refs", lambda: {"image": ("a.jpg", jpeg_bytes(gps=INSIDE_HELSINKI, seed=8))}, {},
     "nope", 401, "unauthorized", "invalid API key"),
    ("ref: read-only key", "refs", lambda: {"image": ("a.jpg", jpeg_bytes(gps=INSIDE_HELSINKI, seed=8))}, {},
     READ_KEY, 403, "forbidden", "write"),
    ("query: not an image", "queries", lambda: {"image": ("q.jpg", b"<html>not a photo</html>")}, {},
     READ_KEY, 415, "not_an_image", "not an image"),
    ("query: truncated jpeg", "queries", lambda: {"image": ("q.jpg", _truncated_jpeg())}, {},
     READ_KEY, 422, "corrupt_image", "truncated"),
    ("query: decompression bomb", "queries", lambda: {"image": ("q.png", png_header_only(100_000, 100_000))}, {},
     READ_KEY, 413, "too_many_pixels", "decompression bomb"),
    ("query: exif gps outside the map", "queries", lambda: {"image": ("q.jpg", jpeg_bytes(gps=LUND, seed=9))}, {},
     READ_KEY, 422, "outside_map", "use_exif_gps=false"),
    ("query: prior outside the map", "queries", lambda: {"image": ("q.jpg", jpeg_bytes(seed=9))},
     {"lat": "60.19", "lon": "24.9443"}, READ_KEY, 422, "outside_map", "from request"),
    ("query: only lon", "queries", lambda: {"image": ("q.jpg", jpeg_bytes(seed=9))}, {"lon": "24.94"},
     READ_KEY, 422, "invalid_request", "both lat and lon"),
    ("query: top_n out of range", "queries", lambda: {"image": ("q.jpg", jpeg_bytes(seed=9))}, {"top_n": "500"},
     READ_KEY, 422, "invalid_request", "top_n must be between"),
    ("query: too large", "queries", lambda: {"image": ("q.jpg", b"\xff\xd8" + os.urandom(MAX_IMAGE_BYTES))}, {},
     READ_KEY, 413, "payload_too_large", "limit"),
    ("query: unknown map", "queries-unknown-map", lambda: {"image": ("q.jpg", jpeg_bytes(seed=9))}, {},
     READ_KEY, 404, "not_found", "map 999999 not found"),
    ("query: no API key", "queries", lambda: {"image": ("q.jpg", jpeg_bytes(seed=9))}, {},
     None, 401, "unauthorized", "X-API-Key"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("target", "files", "data", "api_key", "status", "code", "fragment"),
    [case[1:] for case in BAD_INPUTS],
    ids=[case[0] for case in BAD_INPUTS],
)
def test_bad_input_is_rejected_and_nothing_is_stored(
    service: RunningProcess,
    helsinki: dict[str, Any],
    target: str,
    files: Any,
    data: dict[str, str],
    api_key: str | None,
    status: int,
    code: str,
    fragment: str,
) -> None:
    url = {
        "maps": "/v1/maps",
        "refs": f"/v1/maps/{helsinki['id']}/references",
        "refs-unknown-map": "/v1/maps/999999/references",
        "queries": f"/v1/maps/{helsinki['id']}/queries",
        "queries-unknown-map": "/v1/maps/999999/queries",
    }[target]
    before = Unchanged(service)
    with service.client(api_key) as client:
        response = client.post(url, files=files(), data=data)
    assert response.status_code == status, response.text
    error = error_of(response)
    assert error["code"] == code, error
    assert fragment in error["message"], error
    before.check()


def test_reads_need_a_read_key_and_unknown_ids_are_404(service: RunningProcess, helsinki: dict[str, Any]) -> None:
    with service.client(None) as anonymous:
        assert error_of(anonymous.get("/v1/maps"))["code"] == "unauthorized"
        assert anonymous.get("/healthz").status_code == 200
    with service.client(READ_KEY) as reader:
        assert reader.get(f"/v1/maps/{helsinki['id']}").status_code == 200
        assert error_of(reader.delete(f"/v1/maps/{helsinki['id']}"))["code"] == "forbidden"
        for url, what in [
            ("/v1/maps/424242", "map"),
            ("/v1/references/424242", "reference"),
            ("/v1/jobs/424242", "job"),
        ]:
            response = reader.get(url)
            assert response.status_code == 404 and error_of(response)["message"] == f"{what} 424242 not found"
        assert error_of(reader.get("/v1/maps/not-a-number"))["code"] == "invalid_request"
        assert error_of(reader.get("/v1/no-such-route"))["code"] == "not_found"


def test_data_stays_under_the_data_dir(service: RunningProcess, profile: Profile) -> None:
    sqlite_file = service.data_dir / "geoloc.sqlite3"
    assert sqlite_file.exists() != profile.distributed, "SQLite only in the embedded profile"
    assert not list((service.data_dir / "tmp").glob("upload-*")), "no temp upload left behind"


def test_serve_refuses_a_public_host_without_api_keys(tmp_path: Path) -> None:
    env = service_env(tmp_path / "data")
    env.pop("GEOLOC_API_KEYS", None)
    result = subprocess.run(
        [*geoloc_command(), "serve", "--host", "0.0.0.0", "--port", "1"],
        cwd=REPO_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 2
    assert "refusing to listen on 0.0.0.0" in result.stderr and "GEOLOC_API_KEYS" in result.stderr
