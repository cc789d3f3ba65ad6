"""Map uploads in every accepted format through the real API.

``geoloc serve`` with a worker on loopback, a real SQLite file: the files of ``tests/map_files.py``
load with their building counts and read options; every malformed variant gets a clear 4xx and stores
nothing; a file read with two layers is two maps sharing one stored file; a worker labels a reference
on a GeoPackage map through the map copy the API cached.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.maps import MapReadOptions, map_cache_dir, map_cache_path
from geoloc.sim.world import WorldOptions, generate_world, load_world
from tests.conftest import Profile
from tests.map_files import BAD_CASES, MapFiles, write_map_files
from tests.model_fixtures import link_models
from tests.service_fixtures import (
    WRITE_KEY,
    RunningProcess,
    running_service,
    stored_files,
    table_counts,
    wait_for,
)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> MapFiles:
    return write_map_files(tmp_path_factory.mktemp("api_map_files"))


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, built_models: Path, profile: Profile) -> Iterator[RunningProcess]:
    data_dir = tmp_path_factory.mktemp("api-formats") / "data"
    link_models(data_dir, built_models)
    with running_service(data_dir, workers=1, **profile.new_env()) as running:
        yield running


@pytest.fixture(scope="module")
def client(service: RunningProcess) -> Iterator[httpx.Client]:
    with service.client(WRITE_KEY, timeout=120.0) as c:
        yield c


def upload(client: httpx.Client, path: Path, name: str, options: dict[str, str] | None = None) -> httpx.Response:
    data = {"wait_s": "120", "name": name, **(options or {})}
    return client.post("/v1/maps", files={"file": (path.name, path.read_bytes())}, data=data)


def snapshot(service: RunningProcess) -> tuple[dict[str, int], list[str]]:
    return table_counts(service.database), stored_files(service.data_dir)


GOOD = [
    "geojson",
    "geojson.gz",
    "geojson_3857",
    "geojson_3857_crs_option",
    "gpkg",
    "gpkg_buildings_layer",
    "gpkg_building_attribute",
    "shapefile.zip",
    "fgb",
    "osm.gz",
]


@pytest.mark.parametrize("name", GOOD)
def test_each_format_uploads_with_its_buildings(
    client: httpx.Client, service: RunningProcess, files: MapFiles, name: str
) -> None:
    good = files.good[name]
    response = upload(client, good.path, name, good.options)
    assert response.status_code == 201, response.text
    created = response.json()
    assert created["building_count"] == good.buildings and created["source_format"] == good.source_format
    assert created["read_options"] == MapReadOptions(**good.options).as_dict()
    if good.source_format != "osm.gz":
        assert 60.16 < created["bbox"]["min_lat"] < created["bbox"]["max_lat"] < 60.18
    buildings = client.get(f"/v1/maps/{created['id']}/buildings").json()["features"]
    assert len(buildings) == good.buildings
    cached = map_cache_path(map_cache_dir(service.data_dir), created["sha256"], MapReadOptions(**good.options))
    assert cached.is_file(), "the API cached the loaded map for the workers"
    again = upload(client, good.path, f"{name} again", good.options)
    assert again.status_code == 200 and again.json()["id"] == created["id"] and again.json()["duplicate"]


def test_of_several_polygon_layers_the_buildings_layer_is_read_and_the_map_says_so(
    client: httpx.Client, files: MapFiles
) -> None:
    response = upload(client, files.good["gpkg_buildings_layer"].path, "several layers")
    assert response.status_code in (200, 201), response.text
    report = response.json()["repair_report"]
    assert report["layer"] == "buildings"
    assert report["layer_choice"].endswith("read 'buildings', the only one named 'buildings'")
    refused = upload(client, files.good["gpkg"].path, "several layers, none says buildings")
    assert refused.status_code == 422 and refused.json()["error"]["code"] == "layer_required"


def test_a_maps_streets_come_as_geojson_lines_with_their_names(client: httpx.Client, files: MapFiles) -> None:
    osm = upload(client, files.good["osm.gz"].path, "streets").json()
    body = client.get(f"/v1/maps/{osm['id']}/streets")
    assert body.status_code == 200 and body.headers["content-type"] == "application/geo+json"
    collection = body.json()
    assert collection["type"] == "FeatureCollection" and collection["attribution"] == osm["attribution"]
    streets = collection["features"]
    assert len(streets) > 100 and all(f["geometry"]["type"] == "LineString" for f in streets)
    assert [f["properties"]["street_id"] for f in streets] == list(range(len(streets)))
    names = {f["properties"]["name"] for f in streets} - {None}
    assert {"Unter den Linden", "Friedrichstraße"} <= names  # the ways' OSM name tags
    lon, lat = np.array([c for f in streets for c in f["geometry"]["coordinates"]]).T
    box = osm["bbox"]
    assert box["min_lon"] - 0.05 < lon.min() < lon.max() < box["max_lon"] + 0.05
    assert box["min_lat"] - 0.05 < lat.min() < lat.max() < box["max_lat"] + 0.05
    gis = upload(client, files.good["geojson"].path, "no streets").json()
    assert client.get(f"/v1/maps/{gis['id']}/streets").json()["features"] == []
    missing = client.get("/v1/maps/987654/streets")
    assert missing.status_code == 404 and missing.json()["error"]["code"] == "not_found"


def test_mercator_geojson_without_crs_is_refused_with_the_way_out(
    client: httpx.Client, service: RunningProcess, files: MapFiles
) -> None:
    before = snapshot(service)
    response = upload(client, files.bad["mercator geojson without crs"].path, "mercator")
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "crs_not_lonlat"
    assert "EPSG:3857 Web Mercator" in error["message"] and "crs=EPSG:3857" in error["message"]
    assert "helsinki_3857_no_crs.geojson" in error["message"], "the user's file name, not the temp file's"
    assert error["details"]["if_epsg_3857"]["lat"] == pytest.approx(60.17, abs=0.01)
    assert snapshot(service) == before


@pytest.mark.parametrize("case", BAD_CASES)
def test_malformed_map_is_refused_and_nothing_is_stored(
    client: httpx.Client, service: RunningProcess, files: MapFiles, case: str
) -> None:
    bad = files.bad[case]
    before = snapshot(service)
    response = upload(client, bad.path, "bad", bad.options)
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == bad.code and bad.fragment in error["message"], error
    assert client.get("/healthz").status_code == 200
    assert snapshot(service) == before, "database and stored files unchanged"
    assert not list(map_cache_dir(service.data_dir).glob(".*.tmp")), "no half-written cache file"


@pytest.mark.parametrize(
    ("options", "fragment"),
    [({"crs": "EPSG:99999999"}, "unknown CRS"), ({"crs": "not a crs at all"}, "crs:")],
)
def test_bad_crs_field_is_refused_before_reading(
    client: httpx.Client, service: RunningProcess, files: MapFiles, options: dict[str, str], fragment: str
) -> None:
    before = snapshot(service)
    response = upload(client, files.good["geojson"].path, "x", options)
    assert response.status_code == 422 and response.json()["error"]["code"] == "invalid_request"
    assert fragment in response.json()["error"]["message"]
    assert snapshot(service) == before


def test_two_layers_of_one_file_are_two_maps_sharing_it(
    client: httpx.Client, service: RunningProcess, files: MapFiles
) -> None:
    gpkg = files.good["gpkg"].path
    buildings = upload(client, gpkg, "rakennukset", {"layer": "rakennukset"})
    blocks = upload(client, gpkg, "korttelit", {"layer": "korttelit"})
    assert buildings.status_code in (200, 201) and blocks.status_code == 201, blocks.text
    first, second = buildings.json(), blocks.json()
    assert first["id"] != second["id"] and first["sha256"] == second["sha256"]
    assert second["building_count"] == 5 and second["repair_report"]["layer"] == "korttelit"
    source = service.data_dir / "maps" / f"{second['sha256']}.gpkg"
    cache = map_cache_path(map_cache_dir(service.data_dir), second["sha256"], MapReadOptions(layer="korttelit"))
    assert source.is_file() and cache.is_file()
    assert client.delete(f"/v1/maps/{second['id']}").status_code == 204
    assert source.is_file(), "still read by the other map"
    assert not cache.exists(), "the deleted map's cached copy is gone"
    assert client.get(f"/v1/maps/{first['id']}").status_code == 200


def _wait_labelled(client: httpx.Client, reference_ids: list[int]) -> list[dict[str, Any]]:
    def finished() -> list[dict[str, Any]] | None:
        rows = [client.get(f"/v1/references/{rid}").json() for rid in reference_ids]
        return rows if all(r["status"] in ("done", "failed") for r in rows) else None

    rows: list[dict[str, Any]] = wait_for(finished, timeout=600, interval=1.0, what="references to be labelled")
    return rows


def test_worker_labels_a_reference_on_a_geopackage_map(
    client: httpx.Client, service: RunningProcess, files: MapFiles, tmp_path: Path
) -> None:
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        tmp_path / "world",
        WorldOptions(n_references=3, n_queries=0, seed=5, radius_m=80.0),
    )
    world = load_world(tmp_path / "world")
    good = files.good["gpkg"]
    created = upload(client, good.path, "gpkg for labels", good.options).json()
    ids = []
    for image in world.references:
        response = client.post(
            f"/v1/maps/{created['id']}/references", files={"image": (image.name, image.path.read_bytes())}
        )
        assert response.status_code in (200, 202), response.text
        ids.append(response.json()["id"])
    labelled = _wait_labelled(client, ids)
    assert all(r["status"] == "done" for r in labelled), [r.get("error") for r in labelled]
    seen = [b for r in labelled for b in r["buildings_seen"]]
    assert seen, "the references show buildings of the map"
    # Ids and names come from the layer's attributes (osm_id, NIMI): the worker read the map as uploaded.
    by_id = {b.osm_id: b for b in files.helsinki.buildings}
    assert all(b["osm_id"] in by_id and b["name"] == by_id[b["osm_id"]].name for b in seen)
