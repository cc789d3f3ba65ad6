"""The answer contract: workers build answers as the API's own models before storing them.

A malformed answer fails its job at once with a reason, and a stored answer is always servable.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.answers import QueryResult, RankedLocation, ReferenceLabels
from tests import TESTS_DIR
from tests.answer_plugin import WELL_FORMED, stored_answer
from tests.conftest import Profile
from tests.service_fixtures import WRITE_KEY, RunningProcess, get_job_row, jpeg_bytes, running_service
from workers.handlers import PermanentJobError, answer_checked

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


def test_a_well_formed_answer_is_stored_in_the_served_json_form() -> None:
    stored = stored_answer(copy.deepcopy(WELL_FORMED))
    assert stored == json.loads(QueryResult.model_validate(WELL_FORMED).model_dump_json())
    assert stored["heatmap"]["origin_local_m"] == [-10.0, -10.0]


@pytest.mark.parametrize(
    ("defect", "field", "reason"),
    [
        (lambda a: a["locations"][0].update(lat="north"), "locations.0.lat", "valid number"),
        (lambda a: a["heatmap"]["values"][0].__setitem__(0, math.inf), "heatmap.values.0.0", "finite number"),
        (lambda a: a.pop("camera"), "camera", "Field required"),
        (lambda a: a["buildings"][0].update(colour="red"), "buildings.0.colour", "Extra inputs"),
    ],
)
def test_a_malformed_answer_is_a_permanent_error_naming_the_field(defect: Any, field: str, reason: str) -> None:
    answer = copy.deepcopy(WELL_FORMED)
    defect(answer)
    with pytest.raises(PermanentJobError) as error:
        stored_answer(answer)
    message = str(error.value)
    assert message.startswith("malformed query answer, not stored") and f"{field}: " in message and reason in message


def test_reference_labels_are_checked_too() -> None:
    labels = {
        "estimated": {"lat": 60.17, "lon": 24.94, "heading_deg": 12.5},
        "buildings_seen": copy.deepcopy(WELL_FORMED["buildings"]),
        "timings": {"segmentation": 160.2, "total": 900.0},
    }
    with answer_checked("reference labels"):
        assert ReferenceLabels.model_validate(labels).model_dump(mode="json") == labels
    labels["buildings_seen"][0]["x_end"] = "right"
    with (
        pytest.raises(PermanentJobError, match=r"malformed reference labels.*buildings_seen\.0\.x_end"),
        answer_checked("reference labels"),
    ):
        ReferenceLabels.model_validate(labels)


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
    response = client.post("/v1/maps", files=files, data={"name": "one building"})
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


def test_an_answer_built_directly_fails_for_good_naming_the_field() -> None:
    """The handlers build the models field by field: a bad value fails at once, named, before anything is stored."""
    location = copy.deepcopy(WELL_FORMED["locations"][0])
    location["probability"] = math.nan
    with pytest.raises(PermanentJobError) as error, answer_checked("query answer"):
        RankedLocation(**location)
    message = str(error.value)
    assert message.startswith("malformed query answer, not stored") and "against RankedLocation" in message
    assert "probability: Input should be a finite number" in message
