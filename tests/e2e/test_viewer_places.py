"""The viewer's place search box in a real headless Chromium against a real ``geoloc serve`` (no workers).

Type part of an address, get the service's ranked places as suggestions, choose one: the prior circle is
drawn at the place, and the query sent from the page carries it (the service resolved the name again).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.settings import shared_path
from tests.e2e.test_viewer import Problems, _wait, browser_page
from tests.service_fixtures import WRITE_KEY, jpeg_bytes, running_service

pytestmark = pytest.mark.slow
__all__ = ["browser_page"]  # the fixture, imported to be used here


@pytest.fixture
def helsinki_service(tmp_path: Path) -> Iterator[tuple[str, httpx.Client]]:
    with running_service(tmp_path / "data", workers=0) as service, service.client(WRITE_KEY) as api:
        path = shared_path("data", "osm", "helsinki.osm.pbf")
        with path.open("rb") as f:
            assert (
                api.post(
                    "/v1/maps", files={"file": (path.name, f)}, data={"wait_s": "120", "name": "helsinki"}
                ).status_code
                == 201
            )
        yield service.base_url, api


def test_the_search_box_sets_the_query_place(
    browser_page: tuple[Any, Problems], helsinki_service: tuple[str, httpx.Client], tmp_path: Path
) -> None:
    page, problems = browser_page
    base_url, api = helsinki_service
    page.goto(f"{base_url}/viewer")
    page.get_by_label("API key", exact=True).fill(WRITE_KEY)
    page.get_by_role("button", name="Use key").click()
    _wait(page, "() => Number(document.body.dataset.buildingsDrawn) > 0", 60)
    map_id = int(page.evaluate("window.viewer.state.map.id"))
    expected = api.get(f"/v1/maps/{map_id}/places", params={"q": "Mannerheimintie 5", "limit": 8}).json()["places"]

    box = page.locator("#prior-place")
    box.fill("mannerheimintie 5")
    options = page.locator("#place-options li")
    options.first.wait_for(state="visible")
    assert options.all_inner_texts() == [f"{p['name']} · {p['kind']}" for p in expected]
    box.press("ArrowDown")
    box.press("Enter")
    assert box.input_value() == "Mannerheimintie 5"
    assert page.locator("#place-options").is_hidden()
    place = page.evaluate("window.viewer.state.place")
    assert (place["name"], place["kind"], place["lat"], place["lon"]) == (
        "Mannerheimintie 5",
        "address",
        expected[0]["lat"],
        expected[0]["lon"],
    )
    prior = page.evaluate("window.viewer.view.prior")
    assert prior == {"lat": expected[0]["lat"], "lon": expected[0]["lon"], "radius_m": expected[0]["radius_m"]}

    photo = tmp_path / "photo.jpg"
    photo.write_bytes(jpeg_bytes(seed=7, gps=(60.1716, 24.9443)))  # the place wins over the EXIF GPS
    page.locator("#query-file").set_input_files(str(photo))
    page.get_by_role("button", name="Locate", exact=True).click()
    _wait(page, "() => document.getElementById('answer').dataset.queryId", 30)
    query_id = int(page.locator("#answer").get_attribute("data-query-id"))
    stored = api.get(f"/v1/queries/{query_id}").json()["params"]["prior"]
    assert stored["source"] == "place" and stored["place"] == "Mannerheimintie 5"
    assert (stored["lat"], stored["lon"]) == (expected[0]["lat"], expected[0]["lon"])
    assert problems == [], problems
