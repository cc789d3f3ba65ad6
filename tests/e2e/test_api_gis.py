"""What people who run it expect, through a real server on loopback, on both profiles.

Attribution on maps, answers and GeoJSON; ``/v1/about``; GeoJSON answers (``Accept: application/geo+json``,
``?format=geojson``) of worker-built answers (the answer plugin's worker stores a well-formed answer as the
real handler does); HEIC photos uploaded as queries and references, read as their JPEG twins.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import shapely.geometry

from contracts.licenses import LICENSES, OSM_ATTRIBUTION
from contracts.settings import shared_path
from tests import TESTS_DIR
from tests.conftest import Profile
from tests.geojson_checks import check_query_collection
from tests.service_fixtures import (
    INSIDE_ONE_BUILDING,
    ONE_BUILDING,
    WRITE_KEY,
    jpeg_bytes,
    phone_photo_twins,
    running_service,
)

pytestmark = pytest.mark.slow  # real servers and workers (tests/e2e/ is the slow suite)
GEOJSON = {"Accept": "application/geo+json"}
STATED = "© Stadt Berlin, Geoportal, dl-de/by-2-0"
BERLIN_PHOTO = shared_path("data", "berlin", "images", "01.jpg")
# 20 m around the first Berlin photo's GPS (52.518917, 13.400294), so that its EXIF prior lies on the map
BERLIN_BUILDING = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "properties": {"building": "yes", "name": "Dom"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [
                    [[13.4004, 52.5190], [13.4008, 52.5190], [13.4008, 52.5192], [13.4004, 52.5192], [13.4004, 52.5190]]
                ],
            },
        }
    ],
}
TINY_OSM = b"""<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="test">
  <node id="1" lat="60.1700" lon="24.9400"/><node id="2" lat="60.1700" lon="24.9404"/>
  <node id="3" lat="60.1702" lon="24.9404"/><node id="4" lat="60.1702" lon="24.9400"/>
  <way id="10"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="4"/><nd ref="1"/><tag k="building" v="yes"/></way>
</osm>
"""


@pytest.fixture(scope="module")
def answering(tmp_path_factory: pytest.TempPathFactory, built_models: Path, profile: Profile) -> Iterator[httpx.Client]:
    """A service whose worker answers every query with the plugin's well-formed answer."""
    env = {"GEOLOC_WORKER_PLUGINS": str(TESTS_DIR / "answer_plugin.py"), **profile.new_env()}
    data_dir = tmp_path_factory.mktemp("gis-answers") / "data"
    with running_service(data_dir, models=built_models, **env) as service, service.client(WRITE_KEY) as client:
        yield client


@pytest.fixture(scope="module")
def idle(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[httpx.Client]:
    """A service whose only worker parses maps: photo uploads stay queued."""
    data_dir = tmp_path_factory.mktemp("gis-idle") / "data"
    with running_service(data_dir, workers=0, **profile.new_env()) as service, service.client(WRITE_KEY) as client:
        yield client


def _upload_map(client: httpx.Client, name: str, content: bytes, **fields: str) -> dict[str, Any]:
    response = client.post("/v1/maps", files={"file": (name, content)}, data={"wait_s": "120", "name": name, **fields})
    assert response.status_code == 201, response.text
    return dict(response.json())


@pytest.fixture(scope="module")
def one_building_map(answering: httpx.Client) -> dict[str, Any]:
    """:data:`ONE_BUILDING` stored once per service (tests of this module on one xdist worker share it)."""
    return _upload_map(answering, "one.geojson", json.dumps(ONE_BUILDING).encode(), attribution=STATED)


def test_maps_carry_the_stated_attribution_else_openstreetmaps(answering: httpx.Client) -> None:
    osm = _upload_map(answering, "tiny.osm", TINY_OSM)
    plain = _upload_map(answering, "plain.geojson", json.dumps(BERLIN_BUILDING).encode())
    stated_file = copy.deepcopy(BERLIN_BUILDING)
    stated_file["features"][0]["properties"]["name"] = "Dom (Geoportal)"
    stated = _upload_map(answering, "stated.geojson", json.dumps(stated_file).encode(), attribution=f"  {STATED} ")
    assert (osm["source_format"], osm["attribution"]) == ("osm", OSM_ATTRIBUTION)
    assert (plain["source_format"], plain["attribution"]) == ("geojson", OSM_ATTRIBUTION)
    assert stated["attribution"] == STATED
    assert answering.get(f"/v1/maps/{stated['id']}").json()["attribution"] == STATED
    listed = {m["id"]: m["attribution"] for m in answering.get("/v1/maps").json()["maps"]}
    assert listed[osm["id"]] == OSM_ATTRIBUTION and listed[stated["id"]] == STATED
    buildings = answering.get(f"/v1/maps/{stated['id']}/buildings")
    assert buildings.headers["content-type"].startswith("application/geo+json")
    assert buildings.json()["attribution"] == STATED and len(buildings.json()["features"]) == 1
    again = answering.post(
        "/v1/maps",
        files={"file": ("stated.geojson", json.dumps(stated_file).encode())},
        data={"wait_s": "120", "name": "again", "attribution": "something else"},
    )
    assert again.status_code == 200 and again.json()["attribution"] == STATED  # the stored map, as it was stored
    too_long = answering.post(
        "/v1/maps", files={"file": ("x.osm", TINY_OSM)}, data={"wait_s": "120", "name": "x", "attribution": "©" * 501}
    )
    assert too_long.status_code == 422 and too_long.json()["error"]["code"] == "invalid_request"


def test_about_lists_the_licences(answering: httpx.Client) -> None:
    about = answering.get("/v1/about").json()
    assert about["map_attribution_default"] == OSM_ATTRIBUTION and about["version"]
    assert [entry["name"] for entry in about["licenses"]] == [entry.name for entry in LICENSES]
    assert all(entry["license"] and entry["source"] for entry in about["licenses"])


def test_an_answer_as_geojson_has_poses_view_cones_and_the_buildings(
    answering: httpx.Client, one_building_map: dict[str, Any]
) -> None:
    map_row = one_building_map
    query = answering.post(
        f"/v1/maps/{map_row['id']}/queries",
        files={"image": ("q.jpg", jpeg_bytes(seed=1))},
        data={"top_n": "1", "wait_s": "30"},
    ).json()
    assert query["status"] == "done" and query["attribution"] == STATED, query
    served = answering.get(f"/v1/queries/{query['id']}", headers=GEOJSON)
    assert served.status_code == 200 and served.headers["content-type"].startswith("application/geo+json")
    by_type = check_query_collection(served.json(), query)
    (building,) = by_type["building"]
    footprint = answering.get(f"/v1/maps/{map_row['id']}/buildings").json()["features"][0]["geometry"]
    assert shapely.geometry.shape(building["geometry"]).equals(shapely.geometry.shape(footprint))
    assert building["properties"]["building_id"] == query["result"]["buildings"][0]["building_id"]
    assert answering.get(f"/v1/queries/{query['id']}", params={"format": "geojson"}).json() == served.json()
    as_json = answering.get(f"/v1/queries/{query['id']}", params={"format": "json"}, headers=GEOJSON)
    assert as_json.headers["content-type"].startswith("application/json") and as_json.json()["result"]
    points = answering.get(f"/v1/queries/{query['id']}/answer.geojson").json()
    assert points["attribution"] == STATED and points["features"] == by_type["pose"]
    bad = answering.get(f"/v1/queries/{query['id']}", params={"format": "kml"})
    assert bad.status_code == 422 and "format" in bad.text


def test_a_failed_query_as_geojson_is_an_empty_collection_with_the_reason(
    answering: httpx.Client, one_building_map: dict[str, Any]
) -> None:
    map_id = one_building_map["id"]
    failed = answering.post(
        f"/v1/maps/{map_id}/queries", files={"image": ("q.jpg", jpeg_bytes())}, data={"top_n": "2", "wait_s": "30"}
    ).json()
    assert failed["status"] == "failed"
    served = answering.get(f"/v1/queries/{failed['id']}", params={"format": "geojson"})
    assert served.status_code == 200
    body = served.json()
    assert body["features"] == [] and body["status"] == "failed" and "malformed" in body["error"]


@pytest.mark.skipif(not BERLIN_PHOTO.is_file(), reason="needs shared/data/berlin")
def test_a_heic_query_gets_the_same_priors_as_its_jpeg_twin(idle: httpx.Client) -> None:
    map_id = _upload_map(idle, "berlin.geojson", json.dumps(BERLIN_BUILDING).encode())["id"]
    jpeg, heic = phone_photo_twins(BERLIN_PHOTO)
    params = []
    for name, data in (("IMG_0001.jpg", jpeg), ("IMG_0001.HEIC", heic)):
        response = idle.post(f"/v1/maps/{map_id}/queries", files={"image": (name, data)}, data={"wait_s": "0"})
        assert response.status_code == 202, response.text
        params.append({k: v for k, v in response.json()["params"].items() if k != "original_filename"})
        pending = idle.get(f"/v1/queries/{response.json()['id']}", headers=GEOJSON)
        assert pending.status_code == 200 and pending.json()["features"] == [] and pending.json()["status"] == "queued"
        stored = idle.get(f"/v1/queries/{response.json()['id']}/image")
        assert stored.content == data
    assert stored.headers["content-type"] == "image/heic"
    from_jpeg, from_heic = params
    assert from_heic == from_jpeg
    assert from_heic["prior"]["source"] == "exif"
    assert from_heic["prior"]["lat"] == pytest.approx(52.518916667, abs=1e-6)
    assert from_heic["prior_heading_deg"] == pytest.approx(54.74463, abs=1e-4)


@pytest.mark.skipif(not BERLIN_PHOTO.is_file(), reason="needs shared/data/berlin")
def test_a_heic_reference_and_the_references_as_geojson(idle: httpx.Client) -> None:
    map_id = _upload_map(idle, "berlin-refs.geojson", json.dumps({**BERLIN_BUILDING, "name": "refs"}).encode())["id"]
    jpeg, heic = phone_photo_twins(BERLIN_PHOTO)
    ids = []
    for name, data in (("IMG_0002.jpg", jpeg), ("IMG_0002.heic", heic)):
        response = idle.post(f"/v1/maps/{map_id}/references", files={"image": (name, data)})
        assert response.status_code == 202, response.text
        ids.append(response.json()["id"])
    from_jpeg, from_heic = (idle.get(f"/v1/references/{i}").json() for i in ids)
    for key in ("position", "prior_heading_deg", "prior_heading_accuracy_deg", "focal_length_35mm", "width"):
        assert from_heic[key] == from_jpeg[key], key
    assert from_heic["attribution"] == OSM_ATTRIBUTION and from_heic["position"]["source"] == "exif"
    collection = idle.get(f"/v1/maps/{map_id}/references", headers=GEOJSON).json()
    assert collection["type"] == "FeatureCollection" and collection["attribution"] == OSM_ATTRIBUTION
    assert [f["id"] for f in collection["features"]] == ids
    for feature, ref in zip(collection["features"], (from_jpeg, from_heic), strict=True):
        assert shapely.geometry.shape(feature["geometry"]).is_valid
        assert feature["geometry"]["coordinates"] == [ref["position"]["lon"], ref["position"]["lat"]]
        assert feature["properties"]["pose_source"] == "exif" and feature["properties"]["status"] == "queued"


@pytest.mark.skipif(not BERLIN_PHOTO.is_file(), reason="needs shared/data/berlin")
def test_a_corrupt_heic_gets_a_4xx_with_a_reason(idle: httpx.Client) -> None:
    map_id = _upload_map(idle, "one.geojson", json.dumps(ONE_BUILDING).encode())["id"]
    heic = phone_photo_twins(BERLIN_PHOTO)[1]
    for broken in (heic[:3000], heic[:40] + bytes(200)):
        response = idle.post(
            f"/v1/maps/{map_id}/references", files={"image": ("broken.heic", broken)}, data=INSIDE_ONE_BUILDING
        )
        assert 400 <= response.status_code < 500, response.text
        error = response.json()["error"]
        assert error["code"] in ("corrupt_image", "not_an_image") and error["message"], error
        assert "/tmp" not in response.text and "Traceback" not in response.text  # no server path, no stack
