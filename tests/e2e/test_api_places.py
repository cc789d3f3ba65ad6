"""Places named in the map against a real ``geoloc serve`` on loopback: search, and the ``place`` field.

Helsinki (the real extract) and Berlin Mitte: an address, a named building, a street, an ambiguous name
(422 with candidates), an unknown one (422, nothing stored), and a place overriding EXIF GPS. No worker
runs: the queries stay queued, their stored parameters say which place they use.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.settings import shared_path
from tests.conftest import Profile
from tests.service_fixtures import WRITE_KEY, RunningProcess, jpeg_bytes, running_service, table_counts

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[RunningProcess]:
    with running_service(tmp_path_factory.mktemp("places") / "data", workers=0, **profile.new_env()) as running:
        yield running


@pytest.fixture(scope="module")
def client(service: RunningProcess) -> Iterator[httpx.Client]:
    with service.client(WRITE_KEY) as c:
        yield c


def _upload(client: httpx.Client, path: Path, name: str) -> int:
    with path.open("rb") as f:
        response = client.post("/v1/maps", files={"file": (path.name, f)}, data={"wait_s": "120", "name": name})
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


@pytest.fixture(scope="module")
def helsinki(client: httpx.Client) -> int:
    return _upload(client, shared_path("data", "osm", "helsinki.osm.pbf"), "helsinki")


@pytest.fixture(scope="module")
def berlin(client: httpx.Client) -> int:
    return _upload(client, shared_path("data", "berlin", "berlin_mitte.osm.gz"), "berlin")


def _query(client: httpx.Client, map_id: int, data: dict[str, str], photo: bytes | None = None) -> httpx.Response:
    files = {"image": ("photo.jpg", photo or jpeg_bytes(seed=3), "image/jpeg")}
    return client.post(f"/v1/maps/{map_id}/queries", files=files, data={"wait_s": "0", **data})


def _distance_m(a: tuple[float, float], b: tuple[float, float]) -> float:
    north = math.radians(a[0] - b[0]) * 6_371_000
    east = math.radians(a[1] - b[1]) * 6_371_000 * math.cos(math.radians(a[0]))
    return math.hypot(north, east)


def test_search_ranks_places_for_autocompletion(client: httpx.Client, helsinki: int) -> None:
    response = client.get(f"/v1/maps/{helsinki}/places", params={"q": "mannerheimint", "limit": 3})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["query"] == "mannerheimint" and len(body["places"]) == 3
    first = body["places"][0]
    assert (first["name"], first["kind"]) == ("Mannerheimintie", "street")
    scores = [p["score"] for p in body["places"]]
    assert scores == sorted(scores, reverse=True)
    assert client.get(f"/v1/maps/{helsinki}/places", params={"q": "Xyzzy Plugh"}).json()["places"] == []
    assert client.get(f"/v1/maps/{helsinki}/places", params={"q": ""}).status_code == 422
    assert client.get("/v1/maps/999/places", params={"q": "x"}).status_code == 404


def test_an_address_is_the_query_prior(client: httpx.Client, helsinki: int) -> None:
    found = client.get(f"/v1/maps/{helsinki}/places", params={"q": "Mannerheimintie 5", "limit": 1}).json()["places"]
    assert found[0]["kind"] == "address" and found[0]["building_id"] is not None
    response = _query(client, helsinki, {"place": "mannerheimintie 5"})
    assert response.status_code == 202, response.text
    prior = response.json()["params"]["prior"]
    assert prior["source"] == "place" and prior["place"] == "Mannerheimintie 5" and prior["place_kind"] == "address"
    assert (prior["lat"], prior["lon"], prior["radius_m"]) == (found[0]["lat"], found[0]["lon"], found[0]["radius_m"])
    stored = client.get(f"/v1/queries/{response.json()['id']}").json()["params"]["prior"]
    assert stored == prior


def test_a_street_and_a_radius_given(client: httpx.Client, helsinki: int) -> None:
    response = _query(client, helsinki, {"place": "Aleksanterinkatu", "radius_m": "120"})
    assert response.status_code == 202, response.text
    prior = response.json()["params"]["prior"]
    assert prior["place_kind"] == "street" and prior["radius_m"] == 120.0


def test_a_named_building_on_berlin(client: httpx.Client, berlin: int) -> None:
    response = _query(client, berlin, {"place": "Berliner Dom"})
    assert response.status_code == 202, response.text
    prior = response.json()["params"]["prior"]
    assert prior["place_kind"] == "building" and prior["place"] == "Berliner Dom"
    assert _distance_m((prior["lat"], prior["lon"]), (52.51907, 13.40106)) < 30  # the cathedral's middle
    assert 50 < prior["radius_m"] < 150


def test_a_place_overrides_exif_gps(client: httpx.Client, helsinki: int) -> None:
    photo = jpeg_bytes(seed=4, gps=(60.1716, 24.9443))
    response = _query(client, helsinki, {"place": "Aleksanterinkatu"}, photo)
    assert response.status_code == 202, response.text
    assert response.json()["params"]["prior"]["source"] == "place"
    both = _query(client, helsinki, {"place": "Aleksanterinkatu", "lat": "60.17", "lon": "24.94"})
    assert both.status_code == 422 and both.json()["error"]["code"] == "invalid_request"


def _error(response: httpx.Response) -> dict[str, Any]:
    assert response.status_code == 422, response.text
    return dict(response.json()["error"])


def test_ambiguous_and_unknown_places_are_422_and_store_nothing(
    client: httpx.Client, service: RunningProcess, berlin: int, helsinki: int
) -> None:
    before = table_counts(service.database)
    error = _error(_query(client, berlin, {"place": "Motel One"}))
    assert error["code"] == "ambiguous_place"
    candidates = error["details"]["candidates"]
    assert len(candidates) >= 2 and all(set(c) == {"name", "kind", "lat", "lon"} for c in candidates)
    assert {c["name"] for c in candidates} == {"Motel One"}
    assert _distance_m((candidates[0]["lat"], candidates[0]["lon"]), (candidates[1]["lat"], candidates[1]["lon"])) > 100
    error = _error(_query(client, helsinki, {"place": "Xyzzy Plugh"}))
    assert error["code"] == "unknown_place" and "/places" in error["message"]
    references = client.post(
        f"/v1/maps/{helsinki}/references",
        files={"image": ("ref.jpg", jpeg_bytes(seed=5), "image/jpeg")},
        data={"place": "Xyzzy Plugh"},
    )
    assert _error(references)["code"] == "unknown_place"
    assert table_counts(service.database) == before


def test_a_reference_placed_by_name(client: httpx.Client, berlin: int) -> None:
    found = client.get(f"/v1/maps/{berlin}/places", params={"q": "Alexanderplatz 1", "limit": 1}).json()["places"][0]
    response = client.post(
        f"/v1/maps/{berlin}/references",
        files={"image": ("ref.jpg", jpeg_bytes(seed=6), "image/jpeg")},
        data={"place": "Alexanderplatz 1"},
    )
    assert response.status_code == 202, response.text
    reference = client.get(f"/v1/references/{response.json()['id']}").json()
    assert reference["position"] == {"lat": found["lat"], "lon": found["lon"], "source": "request"}
