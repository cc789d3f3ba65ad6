"""Walks through the service: references of one walk labelled, then placed jointly by the sequence job.

A real server on loopback, real worker processes, the real method on a simulated walk on the Helsinki map whose
photos carry what a phone writes (EXIF GPS, compass, capture time, Mapillary's sequence id).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import httpx
import pytest

from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world, load_world
from tests.conftest import Profile
from tests.service_fixtures import read_rows, running_service, wait_for

pytestmark = pytest.mark.slow  # the real method end to end


@pytest.fixture(scope="module")
def walk_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("walk-world")
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        out,
        WorldOptions(n_references=10, n_queries=1, seed=1, capture="walk"),
    )
    return out


def _upload(client: httpx.Client, map_id: int, path: Path, **form: str) -> dict[str, Any]:
    response = client.post(f"/v1/maps/{map_id}/references", files={"image": (path.name, path.read_bytes())}, data=form)
    assert response.status_code == 202, response.text
    return response.json()


def _angle(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_a_walk_is_labelled_then_placed_jointly(
    tmp_path: Path, built_models: Path, walk_dir: Path, profile: Profile
) -> None:
    world = load_world(walk_dir)
    walk_uuid = world.manifest["walks"][0]["sequence_uuid"]
    with (
        running_service(tmp_path, workers=2, models=built_models, **profile.new_env()) as service,
        service.client(timeout=120.0) as client,
    ):
        osm = shared_path("data", "osm", "helsinki.osm.pbf")
        with osm.open("rb") as f:
            map_id = client.post(
                "/v1/maps", files={"file": (osm.name, f)}, data={"wait_s": "120", "name": "helsinki"}
            ).json()["id"]
        ids = {im.name: _upload(client, map_id, im.path)["id"] for im in world.references}

        def placed() -> dict[int, dict[str, Any]] | None:
            rows = {rid: client.get(f"/v1/references/{rid}").json() for rid in ids.values()}
            failed = [r["error"] for r in rows.values() if r["status"] == "failed"]
            assert not failed, failed
            return rows if all(r["placement"] == "sequence" for r in rows.values()) else None

        rows = wait_for(placed, timeout=600.0, interval=1.0, what="the walk to be placed")
        for image in world.references:
            row = rows[ids[image.name]]
            assert row["status"] == "done" and row["sequence_id"] == walk_uuid
            assert row["capture_time"] is not None and row["capture_time"].startswith("20")
        # Placed poses against the renderer's truth: the walk's headings, as the evaluation measures them.
        headings = [
            _angle(rows[ids[im.name]]["estimated"]["heading_deg"], im.record["pose"]["heading_deg"])
            for im in world.references
        ]
        assert sum(h <= 5.0 for h in headings) >= 8, headings

        # The sequence jobs: one waits per map at a time, and the one that found the walk wholly labelled placed it.
        # Its placements commit before its job row is marked done, so wait for the rows to settle.
        def settled() -> list[dict[str, Any]] | None:
            jobs = read_rows(service.database, "SELECT status, result FROM jobs WHERE kind = 'place_sequence'")
            return None if any(job["status"] in ("queued", "running") for job in jobs) else jobs

        jobs = wait_for(settled, timeout=60.0, interval=0.5, what="the sequence jobs to finish")
        assert 1 <= len(jobs) < len(ids) and all(job["status"] == "done" for job in jobs), jobs
        results = [json.loads(job["result"]) for job in jobs]
        worked = [r for r in results if r["walks"] == 1]
        assert worked and all(r["references"] == len(ids) for r in worked), results
        assert worked[-1]["edges"] > 0 and worked[-1]["placed"] >= 2, worked

        # A photo with a stated sequence is its own walk (not the Mapillary one), alone until it has company;
        # answers keep being served meanwhile.
        extra = _upload(client, map_id, world.queries[0].path, sequence="  my-walk ")
        query = client.post(
            f"/v1/maps/{map_id}/queries",
            files={"image": (world.queries[0].path.name, world.queries[0].path.read_bytes())},
        )
        assert query.status_code == 200 and query.json()["status"] == "done", query.text
        best = query.json()["result"]["locations"][0]
        truth = world.queries[0].record["pose"]
        north_m = (best["lat"] - truth["lat"]) * 111_132.0
        east_m = (best["lon"] - truth["lon"]) * 111_320.0 * math.cos(math.radians(truth["lat"]))
        assert math.hypot(north_m, east_m) < 100.0, (best, truth)  # on the right street, not merely on the map

        def labelled() -> dict[str, Any] | None:
            row = client.get(f"/v1/references/{extra['id']}").json()
            return row if row["status"] == "done" else None

        row = wait_for(labelled, timeout=300.0, interval=1.0, what="the extra reference")
        assert row["sequence_id"] == "my-walk" and row["placement"] == "alone"
