"""A deployment filled through its API, and what it serves, for the backup/restore and upgrade tests.

:func:`fill` uploads a one-building map, three geo-tagged references (labelled by the real method) and a query
answered; :func:`served_state` reads back through the API every map, reference and query answer of that fill, so
that two deployments (before and after a restore, an old release and this checkout) can be compared.
Only the stable public API is used (``/v1/maps``, ``/v1/maps/{id}/references``, ``/v1/references/{id}``,
``/v1/queries/{id}``): the upgrade test runs :func:`fill` against an old release's service.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import httpx

from tests.service_fixtures import ONE_BUILDING, jpeg_bytes, wait_for

REFERENCE_GPS = ((60.1699, 24.9402), (60.1699, 24.9400), (60.1703, 24.9402))
"""Where the references stand: south, south-west and north of the building."""
QUERY_GPS = (60.1699, 24.9401)
QUERY_SEED = 7


@dataclass
class Filled:
    """Ids of what :func:`fill` stored."""

    map_id: int
    reference_ids: list[int]
    query_ids: list[int]


def ask(client: httpx.Client, map_id: int, seed: int = QUERY_SEED) -> dict[str, Any]:
    """Post the query photo of ``seed`` (EXIF GPS near the building) and wait for its answer; the query's JSON."""
    response = client.post(
        f"/v1/maps/{map_id}/queries",
        files={"image": (f"q{seed}.jpg", jpeg_bytes(gps=QUERY_GPS, seed=seed))},
        data={"wait_s": "60"},
    )
    assert response.status_code == 200, response.text
    query = dict(response.json())
    assert query["status"] == "done", query
    return query


def fill(client: httpx.Client) -> Filled:
    """A map, three references labelled (waited for) and one query answered."""
    files = {"file": ("one.geojson", json.dumps(ONE_BUILDING).encode())}
    response = client.post("/v1/maps", files=files, data={"wait_s": "120", "name": "one building"})
    assert response.status_code == 201, response.text
    map_id = int(response.json()["id"])
    reference_ids = []
    for seed, gps in enumerate(REFERENCE_GPS):
        image = {"image": (f"r{seed}.jpg", jpeg_bytes(gps=gps, seed=seed))}
        response = client.post(f"/v1/maps/{map_id}/references", files=image)
        assert response.status_code == 202, response.text
        reference_ids.append(int(response.json()["id"]))

    def labelled() -> bool:
        rows = [client.get(f"/v1/references/{rid}").json() for rid in reference_ids]
        return all(row["status"] in ("done", "failed") for row in rows)

    wait_for(labelled, timeout=120, interval=0.3, what="the references to be labelled")
    return Filled(map_id, reference_ids, [int(ask(client, map_id)["id"])])


def served_state(client: httpx.Client, filled: Filled) -> dict[str, Any]:
    """Every map, the fill's references (listed and one by one) and its queries, as the API serves them."""
    maps = client.get("/v1/maps")
    assert maps.status_code == 200, maps.text
    listed = client.get(f"/v1/maps/{filled.map_id}/references")
    assert listed.status_code == 200, listed.text
    state: dict[str, Any] = {"maps": maps.json()["maps"], "listed_references": listed.json()["references"]}
    for kind, ids in (("references", filled.reference_ids), ("queries", filled.query_ids)):
        rows = [client.get(f"/v1/{kind}/{item}") for item in ids]
        assert all(row.status_code == 200 for row in rows), [row.text for row in rows]
        state[kind] = [row.json() for row in rows]
    return state


def top_pose(query: dict[str, Any]) -> tuple[float, float, float]:
    """The first answer's (lat, lon, heading_deg)."""
    best = query["result"]["locations"][0]
    return (best["lat"], best["lon"], best["heading_deg"])
