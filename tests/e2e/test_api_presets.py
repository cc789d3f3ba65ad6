"""Query presets through a real ``geoloc serve`` on loopback: each is accepted and stored, a bad one refused.

No worker runs: the queries stay queued and their stored parameters say which preset they use (that the
worker answers with the preset's configuration is checked in ``tests/e2e/test_api_method.py``).
"""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest

from contracts.queries import QUERY_PRESETS
from tests.conftest import Profile
from tests.service_fixtures import ONE_BUILDING, WRITE_KEY, jpeg_bytes, read_rows, running_service, table_counts

pytestmark = pytest.mark.slow


def _upload_map(client: httpx.Client) -> int:
    files = {"file": ("hall.geojson", json.dumps(ONE_BUILDING).encode())}
    response = client.post("/v1/maps", files=files, data={"wait_s": "120", "name": "hall"})
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


def _query(client: httpx.Client, map_id: int, data: dict[str, str]) -> httpx.Response:
    files = {"image": ("photo.jpg", jpeg_bytes(seed=5), "image/jpeg")}
    return client.post(f"/v1/maps/{map_id}/queries", files=files, data={"wait_s": "0", **data})


def _stored_preset(database: Path | str, query_id: int) -> str | None:
    stored = read_rows(database, "SELECT params FROM queries WHERE id = ?", (query_id,))[0]["params"]
    params = json.loads(stored) if isinstance(stored, str) else stored
    preset = params.get("preset")
    return None if preset is None else str(preset)


def test_each_preset_is_stored_and_a_bad_one_is_refused(tmp_path: Path, profile: Profile) -> None:
    env = profile.new_env()
    with running_service(tmp_path / "data", workers=0, **env) as service, service.client(WRITE_KEY) as client:
        map_id = _upload_map(client)
        database: Path | str = env.get("GEOLOC_DATABASE_URL") or tmp_path / "data" / "geoloc.sqlite3"
        for preset in QUERY_PRESETS:
            response = _query(client, map_id, {"preset": preset})
            assert response.status_code == 202, response.text
            body = response.json()
            assert body["params"]["preset"] == preset
            assert client.get(f"/v1/queries/{body['id']}").json()["params"]["preset"] == preset
            assert _stored_preset(database, body["id"]) == preset
        # No preset: the service's default (GEOLOC_QUERY_PRESET, balanced), stored with the query.
        default = _query(client, map_id, {})
        assert default.status_code == 202 and default.json()["params"]["preset"] == "balanced"

        before = table_counts(database)
        refused = _query(client, map_id, {"preset": "fastest"})
        assert refused.status_code == 422, refused.text
        error = refused.json()["error"]
        assert error["code"] == "invalid_request" and "preset" in error["message"]
        assert all(f"'{name}'" in error["message"] for name in QUERY_PRESETS), error
        assert table_counts(database) == before  # nothing stored


def test_the_default_preset_is_a_setting(tmp_path: Path, profile: Profile) -> None:
    env = {**profile.new_env(), "GEOLOC_QUERY_PRESET": "fast"}
    with running_service(tmp_path / "data", workers=0, **env) as service, service.client(WRITE_KEY) as client:
        map_id = _upload_map(client)
        assert _query(client, map_id, {}).json()["params"]["preset"] == "fast"
        assert _query(client, map_id, {"preset": "accurate"}).json()["params"]["preset"] == "accurate"
