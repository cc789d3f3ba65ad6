"""Tenants against a real ``geoloc serve`` on loopback, both profiles: a key sees only its tenant's data.

Keys of two tenants (``team-a``, ``team-b``) and an untenanted key. Every operation of the OpenAPI schema with
an id in its path (enumerated from the running service's schema, so a new endpoint is covered, or fails here
until it is) answers another tenant's id, and the untenanted key's, with the same ``404`` and the same body
as an id that does not exist; the owner still reaches it; a foreign ``DELETE`` leaves the row intact; lists
show only the caller's maps; the same map file uploaded by two tenants is two maps. No workers run: the rows
stay queued, which is all a lookup needs.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from db import connect
from tests.conftest import Profile
from tests.service_fixtures import INSIDE_ONE_BUILDING, ONE_BUILDING, RunningProcess, jpeg_bytes, running_service

pytestmark = pytest.mark.slow

A_WRITE, A_READ, B_WRITE, PLAIN = "a-write-key", "a-read-key", "b-write-key", "plain-key"
TENANT_KEYS = f"{A_WRITE}:write@team-a,{A_READ}:read@team-a,{B_WRITE}:read+write@team-b,{PLAIN}:write"
MISSING_ID = 987654321
"""An id no row has."""


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, profile: Profile) -> Iterator[RunningProcess]:
    data_dir = tmp_path_factory.mktemp("tenants") / "data"
    with running_service(data_dir, workers=0, api_keys=TENANT_KEYS, **profile.new_env()) as running:
        yield running


def _upload_map(client: httpx.Client, name: str) -> httpx.Response:
    files = {"file": ("hall.geojson", json.dumps(ONE_BUILDING).encode())}
    return client.post("/v1/maps", files=files, data={"name": name, "wait_s": "120"})


def _seed(client: httpx.Client, name: str) -> dict[str, int]:
    """A map with a reference and a query, as ``client``'s tenant: their ids and the reference's job's."""
    created = _upload_map(client, name)
    assert created.status_code == 201, created.text
    map_id = created.json()["id"]
    reference = client.post(
        f"/v1/maps/{map_id}/references", files={"image": ("r.jpg", jpeg_bytes(seed=21))}, data=INSIDE_ONE_BUILDING
    )
    assert reference.status_code == 202, reference.text
    query = client.post(
        f"/v1/maps/{map_id}/queries",
        files={"image": ("q.jpg", jpeg_bytes(seed=22))},
        data={"use_exif_gps": "false", "wait_s": "0"},
    )
    assert query.status_code == 202, query.text
    track = _post_track(client, f"/v1/maps/{map_id}/tracks", seed=23)
    assert track.status_code == 202, track.text
    return {
        "map_id": map_id,
        "reference_id": reference.json()["id"],
        "query_id": query.json()["id"],
        "track_id": track.json()["id"],
        "job_id": reference.json()["job_id"],
    }


def _post_track(client: httpx.Client, url: str, seed: int) -> httpx.Response:
    """A two-frame track of photos with no GPS, not waited for."""
    files = [("images", (f"f{i}.jpg", jpeg_bytes(seed=seed + i))) for i in range(2)]
    return client.post(url, files=files, data={"use_exif_gps": "false", "wait_s": "0"})


@pytest.fixture(scope="module")
def seeded(service: RunningProcess) -> dict[str, dict[str, int]]:
    """Each key's rows: team-a's, team-b's and the untenanted key's (the same map file for all three)."""
    out = {}
    for key in (A_WRITE, B_WRITE, PLAIN):
        with service.client(key) as client:
            out[key] = _seed(client, f"map of {key}")
    return out


def _operations_with_ids(service: RunningProcess) -> list[tuple[str, str]]:
    spec = httpx.get(f"{service.base_url}/openapi.json", timeout=10).json()
    found = [
        (method.upper(), path)
        for path, item in spec["paths"].items()
        for method in item
        if method in ("get", "post", "put", "patch", "delete") and "{" in path
    ]
    assert len(found) >= 17, found
    return sorted(found, key=lambda op: op[0] == "DELETE")  # deletes last: the owner's checks come before


def _request(client: httpx.Client, method: str, path: str, ids: dict[str, int]) -> httpx.Response:
    """``method path`` with the path's ids from ``ids``, and the fields the operation needs to get past its form."""
    names = re.findall(r"{(\w+)}", path)
    missing = [n for n in names if n not in ids]
    assert not missing, f"{method} {path}: this test knows no id for {missing}; add it to _seed"
    url = path.format(**{n: ids[n] for n in names})
    if method == "POST" and path.endswith("/references"):
        return client.post(url, files={"image": ("x.jpg", jpeg_bytes(seed=31))}, data=INSIDE_ONE_BUILDING)
    if method == "POST" and path.endswith("/queries"):
        files = {"image": ("x.jpg", jpeg_bytes(seed=32))}
        return client.post(url, files=files, data={"use_exif_gps": "false", "wait_s": "0"})
    if method == "POST" and path.endswith("/tracks"):
        return _post_track(client, url, seed=33)
    params = {"q": "hall"} if path.endswith("/places") else {}
    return client.request(method, url, params=params)


def _shape(response: httpx.Response, ids: dict[str, int]) -> tuple[int, str]:
    """Status and body with the ids asked replaced by ``ID``: what may differ between two 404s."""
    text = response.text
    for value in sorted({str(v) for v in ids.values()}, key=len, reverse=True):
        text = re.sub(rf"\b{value}\b", "ID", text)
    return response.status_code, text


def test_another_tenants_ids_are_the_same_404_as_missing_ones_on_every_operation(
    service: RunningProcess, seeded: dict[str, dict[str, int]]
) -> None:
    team_a = seeded[A_WRITE]
    missing = dict.fromkeys(team_a, MISSING_ID)
    operations = _operations_with_ids(service)
    with service.client(A_WRITE) as owner, service.client(A_READ) as owner_reader:
        for method, path in operations:
            if method == "GET":
                for client in (owner, owner_reader):
                    response = _request(client, method, path, team_a)
                    assert response.status_code in (200, 409), (method, path, response.status_code, response.text)
    for key in (B_WRITE, PLAIN):
        with service.client(key) as stranger:
            for method, path in operations:
                absent = _shape(_request(stranger, method, path, missing), missing)
                assert absent[0] == 404, (method, path, absent)
                foreign = _shape(_request(stranger, method, path, team_a), team_a)
                assert foreign == absent, (key, method, path, foreign, absent)
    with service.client(A_READ) as owner:
        routes = (
            ("map_id", "/v1/maps"),
            ("reference_id", "/v1/references"),
            ("query_id", "/v1/queries"),
            ("track_id", "/v1/tracks"),
        )
        for name, route in routes:
            response = owner.get(f"{route}/{team_a[name]}")
            assert response.status_code == 200, f"a foreign DELETE removed {name} {team_a[name]}: {response.text}"
        listed = owner.get(f"/v1/maps/{team_a['map_id']}/references").json()
        assert [r["id"] for r in listed["references"]] == [team_a["reference_id"]], "no foreign upload joined it"


def test_lists_show_only_the_callers_maps_and_each_tenant_has_its_own_copy_of_a_file(
    service: RunningProcess, seeded: dict[str, dict[str, int]]
) -> None:
    map_ids = {key: rows["map_id"] for key, rows in seeded.items()}
    assert len(set(map_ids.values())) == 3, "the same file uploaded by three tenants is three maps"
    for key, visible in ((A_WRITE, A_WRITE), (A_READ, A_WRITE), (B_WRITE, B_WRITE), (PLAIN, PLAIN)):
        with service.client(key) as client:
            assert [m["id"] for m in client.get("/v1/maps").json()["maps"]] == [map_ids[visible]], key
            again = _upload_map(client, "again")
            if key == A_READ:
                assert again.status_code == 403
            else:
                assert again.status_code == 200 and again.json()["id"] == map_ids[visible], again.text
                assert again.json()["duplicate"] is True


def test_a_tenant_deletes_its_own_rows(service: RunningProcess, seeded: dict[str, dict[str, int]]) -> None:
    with service.client(B_WRITE) as client:
        rows = _seed_fresh(client)
        assert client.delete(f"/v1/queries/{rows['query_id']}").status_code == 204
        assert client.delete(f"/v1/references/{rows['reference_id']}").status_code == 204
        assert client.delete(f"/v1/maps/{rows['map_id']}").status_code == 204
        assert client.get(f"/v1/maps/{rows['map_id']}").status_code == 404
        job = client.get(f"/v1/jobs/{rows['job_id']}")
        assert job.status_code == 200 and job.json()["status"] == "cancelled", "the job stays, with its tenant"
    for key in (A_WRITE, PLAIN):
        with service.client(key) as client:
            assert client.get(f"/v1/maps/{seeded[key]['map_id']}").status_code == 200
            assert client.get(f"/v1/jobs/{rows['job_id']}").status_code == 404, "a deleted map's job stays team-b's"


def _seed_fresh(client: httpx.Client) -> dict[str, int]:
    """A map of a file no tenant uploaded yet (another name in the GeoJSON), with a reference and a query."""
    collection: dict[str, Any] = json.loads(json.dumps(ONE_BUILDING))
    collection["features"][0]["properties"]["name"] = "fresh hall"
    files = {"file": ("fresh.geojson", json.dumps(collection).encode())}
    created = client.post("/v1/maps", files=files, data={"name": "fresh", "wait_s": "120"})
    assert created.status_code == 201, created.text
    map_id = created.json()["id"]
    reference = client.post(
        f"/v1/maps/{map_id}/references", files={"image": ("r.jpg", jpeg_bytes(seed=41))}, data=INSIDE_ONE_BUILDING
    )
    query = client.post(
        f"/v1/maps/{map_id}/queries",
        files={"image": ("q.jpg", jpeg_bytes(seed=42))},
        data={"use_exif_gps": "false", "wait_s": "0"},
    )
    assert reference.status_code == 202 and query.status_code == 202, (reference.text, query.text)
    return {
        "map_id": map_id,
        "reference_id": reference.json()["id"],
        "query_id": query.json()["id"],
        "job_id": reference.json()["job_id"],
    }


def test_tenant_keys_still_need_their_scope(service: RunningProcess, seeded: dict[str, dict[str, int]]) -> None:
    with service.client(A_READ) as reader:
        response = reader.delete(f"/v1/maps/{seeded[A_WRITE]['map_id']}")
        assert response.status_code == 403 and response.json()["error"]["code"] == "forbidden"
    with service.client("unknown-key") as anonymous:
        assert anonymous.get("/v1/maps").status_code == 401


def test_the_keys_tenant_is_stamped_on_the_map_and_its_jobs(
    service: RunningProcess, seeded: dict[str, dict[str, int]]
) -> None:
    db = connect(service.database)
    try:
        tenants = {row["id"]: row["tenant"] for row in db.query("SELECT id, tenant FROM maps")}
        job_tenants = {row["id"]: row["tenant"] for row in db.query("SELECT id, tenant FROM jobs")}
    finally:
        db.close()
    for key, tenant in ((A_WRITE, "team-a"), (B_WRITE, "team-b"), (PLAIN, None)):
        assert tenants[seeded[key]["map_id"]] == tenant
        assert job_tenants[seeded[key]["job_id"]] == tenant


def test_a_track_of_another_tenants_query_is_as_if_it_did_not_exist(
    service: RunningProcess, seeded: dict[str, dict[str, int]]
) -> None:
    """A JSON track naming team-a's query on team-b's map: the same 404 as a query that does not exist."""
    team_a, team_b = seeded[A_WRITE], seeded[B_WRITE]
    url = f"/v1/maps/{team_b['map_id']}/tracks"
    with service.client(B_WRITE) as client:
        foreign = client.post(url, json={"query_ids": [team_a["query_id"]], "wait_s": 0})
        missing = client.post(url, json={"query_ids": [MISSING_ID], "wait_s": 0})
        own = client.post(url, json={"query_ids": [team_b["query_id"]], "wait_s": 0})
    assert foreign.status_code == missing.status_code == 404, (foreign.text, missing.text)
    assert _shape(foreign, team_a) == _shape(missing, {"query_id": MISSING_ID})
    assert own.status_code == 202, own.text
