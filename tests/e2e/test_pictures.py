"""``GET /v1/queries/{id}/heatmap.png`` through a real server and worker: a picture that stands alone.

The worker's answer is placed on the map by ``tests/picture_plugin.py`` (one pose south of building 0 looking
north, a heat map around it); the test reads the PNG's pixels where the map's footprints, the cone's apex,
the colour bar and the attribution must be.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from contracts.answers import QueryResult
from geoloc.maps import CityMap, load_map
from service import heatmap_png as pictures
from tests import TESTS_DIR
from tests.service_fixtures import WRITE_KEY, RunningProcess, jpeg_bytes, running_service

pytestmark = pytest.mark.slow  # a real server and workers (tests/e2e/ is the slow suite)
PLUGIN = TESTS_DIR / "picture_plugin.py"
ATTRIBUTION = "© Test City survey, CC BY 4.0"


def _square(lon: float, lat: float, side_deg: float) -> list[list[list[float]]]:
    ring = [[lon, lat], [lon + side_deg * 2, lat], [lon + side_deg * 2, lat + side_deg], [lon, lat + side_deg]]
    return [[*ring, ring[0]]]


TWO_BUILDINGS = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "id": f"way/{i + 1}",
            "properties": {"building": "yes", "name": f"B{i}"},
            "geometry": {"type": "Polygon", "coordinates": _square(24.94 + 0.0009 * i, 60.17, 0.00025)},
        }
        for i in range(2)
    ],
}
"""Two 28 x 28 m squares 50 m apart (building 0 west, building 1 east)."""


@pytest.fixture(scope="module")
def map_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("pictures") / "two.geojson"
    path.write_text(json.dumps(TWO_BUILDINGS))
    return path


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, built_models: Path) -> Iterator[RunningProcess]:
    data_dir = tmp_path_factory.mktemp("pictures") / "data"
    with running_service(data_dir, models=built_models, GEOLOC_WORKER_PLUGINS=str(PLUGIN)) as running:
        yield running


@pytest.fixture(scope="module")
def answered(service: RunningProcess, map_file: Path) -> Iterator[tuple[httpx.Client, dict[str, Any]]]:
    with service.client(WRITE_KEY) as client:
        files = {"file": ("two.geojson", map_file.read_bytes())}
        response = client.post(
            "/v1/maps", files=files, data={"wait_s": "120", "name": "two", "attribution": ATTRIBUTION}
        )
        assert response.status_code == 201, response.text
        map_id = response.json()["id"]
        response = client.post(
            f"/v1/maps/{map_id}/queries", files={"image": ("q.jpg", jpeg_bytes(seed=1))}, data={"wait_s": "30"}
        )
        assert response.status_code == 200 and response.json()["status"] == "done", response.text
        yield client, response.json()


def _pixel(image: np.ndarray, col: float, row: float) -> tuple[int, ...]:
    return tuple(int(v) for v in image[round(float(row)), round(float(col))])


def test_the_heatmap_png_draws_the_map_the_poses_and_its_legend(
    answered: tuple[httpx.Client, dict[str, Any]], map_file: Path
) -> None:
    client, query = answered
    response = client.get(f"/v1/queries/{query['id']}/heatmap.png")
    assert response.status_code == 200 and response.headers["content-type"] == "image/png"
    image = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
    assert image.shape == (pictures.SIZE_PX + pictures.FOOTER_PX, pictures.SIZE_PX, 3)

    city: CityMap = load_map(map_file)  # the same file, so the same local frame as the server's
    result = QueryResult.model_validate(query["result"])
    cones = pictures.view_cones(city, result)
    view = pictures.View.around(result, cones)
    poses = np.array([cone[0] for cone in cones])
    east = city.buildings[1].polygon.centroid  # outside the heat map's grid and the cone
    assert _pixel(image, *view.to_px(east.x, east.y)) == pictures.FOOTPRINT_FILL
    west = city.buildings[0].polygon.centroid  # the cone looks at it: still footprint under a blue tint
    tinted = _pixel(image, *view.to_px(west.x, west.y))
    assert tinted != pictures.FOOTPRINT_FILL and tinted[2] > tinted[0]
    apex = view.to_px(poses[0, 0], poses[0, 1])
    assert _pixel(image, *apex) == pictures.CONE_COLORS[0]
    peak_xy = poses[0] - (0.0, 10.0)  # the plugin's peak cell, 10 m south of the pose
    assert _pixel(image, *view.to_px(*peak_xy)) not in {pictures.BACKGROUND, pictures.STREET}

    bar = image[pictures.SIZE_PX + 19, 17:236].astype(int)  # the colour bar's middle row
    brightness = bar.sum(axis=1)
    assert len({tuple(c) for c in bar}) > 100  # a gradient, not a block
    assert brightness[-1] - brightness[0] > 500 and np.mean(np.diff(brightness) >= -3) > 0.95

    corner = image[-24:, -320:].astype(int)  # the attribution, bottom right of the footer
    assert (corner.sum(axis=2) < 300).sum() > 100
    assert (image[-24:, 300:400].astype(int).sum(axis=2) < 300).sum() == 0  # blank left of it: right-aligned text


def test_the_heatmap_png_of_an_unknown_query_is_a_clear_404(answered: tuple[httpx.Client, dict[str, Any]]) -> None:
    client, _ = answered
    response = client.get("/v1/queries/987654/heatmap.png")
    assert response.status_code == 404 and response.json()["error"]["code"] == "not_found"
