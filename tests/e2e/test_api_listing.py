"""The endpoints the browser viewer reads besides the core API.

Against a real ``geoloc serve`` on loopback with no workers (jobs stay queued unless a test moves them
through the real job store): a map's references page by page with its status counts, the stored photos
of references and queries, and the viewer's own routes (page, redirect, configuration, static files).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.jobs import LABEL_REFERENCE, PLACE_SEQUENCE, PlaceSequencePayload
from tests.conftest import Profile
from tests.service_fixtures import READ_KEY, WRITE_KEY, RunningProcess, jpeg_bytes, running_service

pytestmark = pytest.mark.slow

CENTRE = (60.1700, 24.9400)
TOWN = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "properties": {"building": "yes", "name": f"Block {i}"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [
                    [
                        [CENTRE[1] + dx, CENTRE[0] + 0.0004],
                        [CENTRE[1] + dx + 0.0005, CENTRE[0] + 0.0004],
                        [CENTRE[1] + dx + 0.0005, CENTRE[0] + 0.0008],
                        [CENTRE[1] + dx, CENTRE[0] + 0.0008],
                        [CENTRE[1] + dx, CENTRE[0] + 0.0004],
                    ]
                ],
            },
        }
        for i, dx in enumerate((-0.001, 0.0, 0.001))
    ],
}


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[RunningProcess]:
    with running_service(tmp_path_factory.mktemp("listing") / "data", workers=0, **profile.new_env()) as running:
        yield running


@pytest.fixture(scope="module")
def client(service: RunningProcess) -> Iterator[httpx.Client]:
    with service.client(WRITE_KEY) as c:
        yield c


def _new_map(client: httpx.Client, name: str) -> int:
    body = json.dumps({**TOWN, "name": name}).encode()  # a distinct file per map (maps are deduplicated)
    response = client.post("/v1/maps", files={"file": (f"{name}.geojson", body)}, data={"wait_s": "120", "name": name})
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


def _add_references(client: httpx.Client, map_id: int, count: int, seed0: int) -> list[dict[str, Any]]:
    out = []
    for i in range(count):
        photo = jpeg_bytes(gps=(CENTRE[0] + 1e-4 * i, CENTRE[1]), seed=seed0 + i)
        response = client.post(f"/v1/maps/{map_id}/references", files={"image": (f"ref_{i}.jpg", photo)})
        assert response.status_code == 202, response.text
        out.append(response.json())
    return out


def test_references_come_page_by_page_with_counts_for_the_whole_map(client: httpx.Client) -> None:
    map_id = _new_map(client, "paged")
    other_map = _new_map(client, "other")
    accepted = _add_references(client, map_id, 5, seed0=100)
    _add_references(client, other_map, 2, seed0=200)

    pages, after = [], 0
    while True:
        response = client.get(f"/v1/maps/{map_id}/references", params={"after_id": after, "limit": 2})
        assert response.status_code == 200, response.text
        page = response.json()
        pages.append([r["id"] for r in page["references"]])
        assert page["map_id"] == map_id and page["total"] == 5
        assert page["counts"] == {"queued": 5, "processing": 0, "done": 0, "failed": 0}
        if page["next_after_id"] is None:
            break
        assert page["next_after_id"] == page["references"][-1]["id"]
        after = page["next_after_id"]
    ids = [a["id"] for a in accepted]
    assert pages == [ids[:2], ids[2:4], ids[4:]]  # oldest first, nothing skipped or repeated

    everything = client.get(f"/v1/maps/{map_id}/references").json()
    assert [r["id"] for r in everything["references"]] == ids and everything["next_after_id"] is None
    first = everything["references"][0]
    single = client.get(f"/v1/references/{first['id']}").json()
    assert first == single  # the same model as GET /v1/references/{id}
    assert first["original_filename"] == "ref_0.jpg" and first["position"]["source"] == "exif"


def _check_walks_placing_follows_its_job(
    service: RunningProcess, client: httpx.Client, map_id: int, reference_id: int
) -> None:
    """``walks_placing`` counts the map's sequence job while it waits and while it runs, then not."""
    from db import connect
    from db import jobs as job_store

    def placing() -> int:
        return int(client.get(f"/v1/maps/{map_id}/references", params={"limit": 1}).json()["walks_placing"])

    worker = "test-worker:2"
    db = connect(service.database)
    try:
        payload = PlaceSequencePayload(reference_id=reference_id, map_id=map_id)
        job_id = job_store.enqueue_job(db, PLACE_SEQUENCE, payload, map_id=map_id)
        assert placing() == 1
        claimed = job_store.claim_job(db, worker, lease_s=600, kinds=[PLACE_SEQUENCE])
        assert claimed is not None and claimed["id"] == job_id and placing() == 1
        job_store.complete_job(db, job_id, worker, {"placed": 0})
        assert placing() == 0
    finally:
        db.close()


def test_counts_follow_the_jobs(tmp_path: Path, profile: Profile) -> None:
    from db import connect
    from db import jobs as job_store
    from db import references as reference_store

    worker = "test-worker:1"
    env = profile.new_env()
    with running_service(tmp_path / "data", workers=0, **env) as service, service.client(WRITE_KEY) as client:
        map_id = _new_map(client, "statuses")
        accepted = _add_references(client, map_id, 4, seed0=300)
        db = connect(service.database)
        try:  # the job store moves the jobs as a worker would: one running, one failed, one done
            claimed = [job_store.claim_job(db, worker, lease_s=600, kinds=[LABEL_REFERENCE]) for _ in range(3)]
            assert [j["id"] if j else None for j in claimed] == [a["job_id"] for a in accepted[:3]]
            _running, failing, finishing = (j for j in claimed if j is not None)
            job_store.fail_job(db, failing["id"], worker, "deliberate failure", permanent=True)
            reference_store.update_reference_result(db, accepted[2]["id"], status="done", estimated_heading_deg=90.0)
            job_store.complete_job(db, finishing["id"], worker, {"heading_deg": 90.0})
        finally:
            db.close()
        page = client.get(f"/v1/maps/{map_id}/references").json()
        assert page["walks_placing"] == 0
        _check_walks_placing_follows_its_job(service, client, map_id, accepted[2]["id"])
    assert page["counts"] == {"queued": 1, "processing": 1, "done": 1, "failed": 1} and page["total"] == 4
    statuses = [(r["id"], r["status"]) for r in page["references"]]
    assert statuses == list(zip([a["id"] for a in accepted], ["processing", "failed", "done", "queued"], strict=True))
    assert "deliberate failure" in page["references"][1]["error"]
    assert page["references"][2]["estimated"]["heading_deg"] == 90.0


def test_listing_rejects_bad_paging_and_unknown_maps(client: httpx.Client, service: RunningProcess) -> None:
    map_id = _new_map(client, "empty")
    empty = client.get(f"/v1/maps/{map_id}/references").json()
    assert empty["references"] == [] and empty["total"] == 0 and empty["next_after_id"] is None
    for params in ({"limit": 0}, {"limit": 501}, {"after_id": -1}, {"limit": "many"}):
        response = client.get(f"/v1/maps/{map_id}/references", params=params)
        assert response.status_code == 422, (params, response.text)
        assert response.json()["error"]["code"] == "invalid_request"
    missing = client.get("/v1/maps/424242/references")
    assert missing.status_code == 404 and missing.json()["error"]["message"] == "map 424242 not found"
    with service.client(None) as anonymous:
        assert anonymous.get(f"/v1/maps/{map_id}/references").status_code == 401
    with service.client(READ_KEY) as reader:
        assert reader.get(f"/v1/maps/{map_id}/references").status_code == 200


def test_stored_photos_come_back_as_uploaded(client: httpx.Client, service: RunningProcess) -> None:
    map_id = _new_map(client, "photos")
    photo = jpeg_bytes(gps=CENTRE, seed=400)
    reference = client.post(f"/v1/maps/{map_id}/references", files={"image": ("r.jpg", photo)}).json()
    response = client.get(f"/v1/references/{reference['id']}/image")
    assert response.status_code == 200 and response.headers["content-type"] == "image/jpeg"
    assert response.content == photo  # the stored bytes, EXIF included

    query_photo = jpeg_bytes(gps=CENTRE, seed=401)
    query = client.post(f"/v1/maps/{map_id}/queries", files={"image": ("q.jpg", query_photo)}, data={"wait_s": "0"})
    assert query.status_code == 202, query.text
    response = client.get(f"/v1/queries/{query.json()['id']}/image")
    assert response.status_code == 200 and response.headers["content-type"] == "image/jpeg"
    assert response.content == query_photo

    for url, message in (
        ("/v1/references/424242/image", "reference 424242 not found"),
        ("/v1/queries/424242/image", "query 424242 not found"),
    ):
        missing = client.get(url)
        assert missing.status_code == 404 and missing.json()["error"]["message"] == message
    with service.client(None) as anonymous:
        assert anonymous.get(f"/v1/references/{reference['id']}/image").status_code == 401
    with service.client(READ_KEY) as reader:
        assert reader.get(f"/v1/references/{reference['id']}/image").content == photo


def test_the_viewer_is_served_offline_without_a_key(service: RunningProcess) -> None:
    with service.client(None) as anonymous:
        root = anonymous.get("/", follow_redirects=False)
        assert root.status_code == 307 and root.headers["location"] == "viewer"
        page = anonymous.get("/", follow_redirects=True)
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        csp = page.headers["content-security-policy"]
        assert "default-src 'self'" in csp and "script-src 'self'" in csp
        html = page.text
        assert 'src="viewer/static/js/app.js"' in html and "http://" not in html and "https://" not in html
        assert anonymous.get("/viewer/config.json").json() == {"auth_required": True}
        for asset, media in (
            ("viewer/static/js/app.js", "javascript"),
            ("viewer/static/js/mapview.js", "javascript"),
            ("viewer/static/js/api.js", "javascript"),
            ("viewer/static/js/geo.js", "javascript"),
            ("viewer/static/viewer.css", "text/css"),
        ):
            response = anonymous.get(f"/{asset}")
            assert response.status_code == 200 and media in response.headers["content-type"], asset
            text = response.text.replace("http://www.w3.org/2000/svg", "")  # a namespace name, not a fetch
            assert "https://" not in text and "http://" not in text, asset  # nothing is loaded from elsewhere
        assert anonymous.get("/viewer/static/js/nothing.js").status_code == 404
