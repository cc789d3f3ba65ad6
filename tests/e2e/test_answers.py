"""The answer contract: workers build answers as the API's own models before storing them.

Through a real worker and the API: a malformed answer fails its job at once with a reason, and a stored answer
is always servable (the checks themselves: ``tests/unit/workers/test_answer_checks.py``).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests import TESTS_DIR
from tests.answer_plugin import WELL_FORMED, stored_answer
from tests.conftest import Profile
from tests.service_fixtures import WRITE_KEY, RunningProcess, get_job_row, jpeg_bytes, running_service

pytestmark = pytest.mark.slow  # a real server and workers (tests/e2e/ is the slow suite)
PLUGIN = TESTS_DIR / "answer_plugin.py"
ONE_BUILDING = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "id": "way/1",
            "properties": {"building": "yes", "name": "B0"},
            "geometry": {
                "type": "Polygon",
                "coordinates": [
                    [[24.94, 60.17], [24.9402, 60.17], [24.9402, 60.1701], [24.94, 60.1701], [24.94, 60.17]]
                ],
            },
        }
    ],
}


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, built_models: Path, profile: Profile) -> Iterator[RunningProcess]:
    data_dir = tmp_path_factory.mktemp("answers") / "data"
    env = {"GEOLOC_WORKER_PLUGINS": str(PLUGIN), **profile.new_env()}
    with running_service(data_dir, models=built_models, **env) as running:
        yield running


@pytest.fixture(scope="module")
def client(service: RunningProcess) -> Iterator[httpx.Client]:
    with service.client(WRITE_KEY) as c:
        yield c


@pytest.fixture(scope="module")
def map_id(client: httpx.Client) -> int:
    files = {"file": ("one.geojson", json.dumps(ONE_BUILDING).encode())}
    response = client.post("/v1/maps", files=files, data={"wait_s": "120", "name": "one building"})
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


def _ask(client: httpx.Client, map_id: int, top_n: int) -> dict[str, Any]:
    response = client.post(
        f"/v1/maps/{map_id}/queries",
        files={"image": ("q.jpg", jpeg_bytes(seed=top_n))},
        data={"top_n": str(top_n), "wait_s": "30"},
    )
    assert response.status_code == 200, response.text
    return dict(response.json())


def test_a_worker_stores_a_well_formed_answer_and_the_api_serves_it(client: httpx.Client, map_id: int) -> None:
    query = _ask(client, map_id, top_n=1)
    assert query["status"] == "done" and query["error"] is None
    assert query["result"] == stored_answer(copy.deepcopy(WELL_FORMED))
    assert client.get(f"/v1/queries/{query['id']}").json()["result"] == query["result"]


@pytest.mark.parametrize(
    ("top_n", "problem"),
    [
        (2, "locations.0.lat: Input should be a valid number"),
        (3, "locations.0.probability: Input should be a finite"),
        (4, "heatmap: Field required; heat_map: Extra inputs are not permitted"),
    ],
)
def test_a_malformed_answer_fails_the_job_at_once_with_the_reason(
    client: httpx.Client, service: RunningProcess, map_id: int, top_n: int, problem: str
) -> None:
    query = _ask(client, map_id, top_n=top_n)
    assert query["status"] == "failed" and query["result"] is None
    assert "malformed query answer, not stored" in query["error"] and problem in query["error"]
    job = get_job_row(service.database, query["job_id"])
    assert job["status"] == "failed" and job["attempts"] == 1, "a malformed answer is not retried"
    served = client.get(f"/v1/queries/{query['id']}")
    assert served.status_code == 200 and served.json()["status"] == "failed"
