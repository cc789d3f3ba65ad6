"""The viewer draws a track in a real headless Chromium: trajectory, per-frame cones and uncertainty, a stepper.

A real ``geoloc serve`` with workers locates a 3-frame walk (through the API); the page opens
``#map=ID&track=ID`` and what it draws is checked against the API's answer: each frame's dot at its projected
position, the trajectory through them in order, each uncertainty circle's radius, and the stepper moving the
emphasis from frame to frame. No console error, page error or failed request is allowed.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world, load_world
from tests.e2e.test_viewer import Problems, _project, _wait, browser_page  # noqa: F401  (browser_page: a fixture)
from tests.model_fixtures import link_models
from tests.service_fixtures import WRITE_KEY, running_service

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def walk_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("viewer-track-walk")
    options = WorldOptions(n_references=3, n_queries=1, seed=5, capture="walk", width=480, height=360)
    generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), out, options)
    return out


def test_the_viewer_draws_a_track_and_steps_through_its_frames(
    browser_page: tuple[Any, Problems],  # noqa: F811
    tmp_path: Path,
    built_models: Path,
    walk_dir: Path,
) -> None:
    page, problems = browser_page
    photos = sorted(load_world(walk_dir).references, key=lambda im: im.name)
    data_dir = tmp_path / "data"
    link_models(data_dir, built_models)
    with running_service(data_dir, workers=1) as service, service.client(WRITE_KEY, timeout=300.0) as api:
        osm = shared_path("data", "osm", "helsinki.osm.pbf")
        upload = {"file": (osm.name, osm.read_bytes())}
        created = api.post("/v1/maps", files=upload, data={"name": "h", "wait_s": "120"})
        map_id = created.json()["id"]
        files = [("images", (im.path.name, im.path.read_bytes(), "image/jpeg")) for im in photos]
        track = api.post(f"/v1/maps/{map_id}/tracks", files=files, data={"wait_s": "280"}).json()
        assert track["status"] == "done", track
        frames = [f for f in track["frames"] if f["lat"] is not None]
        assert len(frames) == 3

        page.goto(f"{service.base_url}/viewer#map={map_id}&track={track['id']}")
        page.get_by_label("API key", exact=True).fill(WRITE_KEY)
        page.get_by_role("button", name="Use key").click()
        _wait(page, "() => document.querySelectorAll('.track-frame').length === 3", 60)
        _wait(page, "() => document.body.dataset.trackFrame !== undefined", 30)
        assert page.locator("#track-frame-label").inner_text() == "Frame 1 of 3"
        assert page.locator(".track-frame.selected").get_attribute("data-index") == str(frames[0]["index"])

        scale = float(page.evaluate("window.viewer.scale()"))
        centres = []
        for frame in frames:
            el = page.locator(f".track-frame[data-index='{frame['index']}']")
            dot = el.locator(".dot").bounding_box()
            assert dot is not None
            x, y = _project(page, frame["lat"], frame["lon"])
            assert abs(dot["x"] + dot["width"] / 2 - x) < 2 and abs(dot["y"] + dot["height"] / 2 - y) < 2, frame
            centres.append((x, y))
            radius = float(el.locator(".track-uncertainty").get_attribute("r") or "0")
            assert radius == pytest.approx(frame["uncertainty_radius_m"] * scale, rel=1e-3)
            assert el.locator(".cone").get_attribute("d")
        line = page.locator(".track-line").get_attribute("d") or ""
        box = page.locator("#map").bounding_box()
        assert box is not None
        numbers = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", line)]
        drawn = [(box["x"] + numbers[i], box["y"] + numbers[i + 1]) for i in range(0, len(numbers), 2)]
        assert len(drawn) == 3
        for (dx, dy), (x, y) in zip(drawn, centres, strict=True):
            assert abs(dx - x) < 2 and abs(dy - y) < 2

        page.get_by_role("button", name="Next frame").click()
        assert page.locator("#track-frame-label").inner_text() == "Frame 2 of 3"
        assert page.locator(".track-frame.selected").get_attribute("data-index") == str(frames[1]["index"])
        page.get_by_role("button", name="Next frame").click()
        assert page.get_by_role("button", name="Next frame").is_disabled()
        page.get_by_role("button", name="Previous frame").click()
        assert page.evaluate("document.body.dataset.trackFrame") == str(frames[1]["index"])
        assert "track=" in page.url
    assert not problems, problems
