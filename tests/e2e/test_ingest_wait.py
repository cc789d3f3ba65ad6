"""``geoloc ingest --wait`` on a simulated walk: it returns once the walk is placed, every pose final (issue 50).

A real ``geoloc serve`` on loopback with two real worker processes and the real method; the photos carry what a
phone writes (EXIF GPS, compass, capture time, Mapillary's sequence id). The embedded profile only: the wait is
the client's, read through the API, the same on both profiles (the placement itself runs on both in
``tests/e2e/test_api_sequences.py``). The wait's steps against a mock service: ``tests/unit/cli/test_ingest_wait.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest

from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world
from tests.service_fixtures import REPO_ROOT, WRITE_KEY, geoloc_command, running_service

pytestmark = pytest.mark.slow  # the real method end to end


def test_wait_returns_once_the_map_s_walks_are_placed(tmp_path: Path, built_models: Path) -> None:
    world = tmp_path / "world"
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        world,
        WorldOptions(n_references=5, n_queries=0, seed=3, capture="walk"),
    )
    with (
        running_service(tmp_path / "data", workers=2, models=built_models) as service,
        service.client(WRITE_KEY, timeout=120.0) as client,
    ):
        osm = shared_path("data", "osm", "helsinki.osm.pbf")
        with osm.open("rb") as f:
            answer = client.post("/v1/maps", files={"file": (osm.name, f)}, data={"wait_s": "120", "name": "helsinki"})
        assert answer.status_code == 201, answer.text
        map_id = answer.json()["id"]
        out = tmp_path / "ingest.json"
        args = ["ingest", str(world / "references"), "--map", str(map_id), "--wait", "--json", str(out)]
        result = subprocess.run(
            [*geoloc_command(), *args, "--url", str(service.base_url), "--api-key", WRITE_KEY],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            timeout=300,
            env={**os.environ, "COLUMNS": "200"},
            check=False,
        )
        assert result.returncode == 0, result.stdout + result.stderr
        # Read right after the command returned: nothing of the map may still move.
        listing = client.get(f"/v1/maps/{map_id}/references", params={"limit": 500}).json()

    assert "placing walks" in result.stderr and "every pose is final" in result.stdout
    assert listing["walks_placing"] == 0 and listing["counts"]["done"] == listing["total"] == 5, listing["counts"]
    walks: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for reference in listing["references"]:
        walks[reference["sequence_id"]].append(reference)
    assert None not in walks and any(len(frames) >= 2 for frames in walks.values()), walks.keys()
    for sequence, frames in walks.items():
        if len(frames) >= 2:
            assert [r["placement"] for r in frames] == ["sequence"] * len(frames), sequence
    report = json.loads(out.read_text())
    assert report["wait_for"] == "placed" and report["labelling"] == {"done": 5}
    walks_of_two = sum(len(frames) >= 2 for frames in walks.values())
    assert report["placement"]["walks"] == report["placement"]["placed"] == walks_of_two
    assert report["placement"]["walks_placing"] == 0 and report["placement"]["unplaced"] == []
