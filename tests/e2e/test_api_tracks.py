"""Tracks through the service: a short walk's photos located together, end to end, on both profiles.

A real server on loopback, real worker processes, the real method on a tiny simulated walk on the Helsinki map
(its photos carry EXIF GPS, compass and capture time): a track through multipart with the sync client, its frames
in order with their poses, the GeoJSON form, each frame's query, the async client, a track of earlier queries
ordered by capture time, ``geoloc locate-track`` against the service, and deletion.
"""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from client import AsyncClient, Client
from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world, load_world
from tests.conftest import Profile
from tests.service_fixtures import WRITE_KEY, geoloc_command, running_service, stored_files

pytestmark = pytest.mark.slow  # the real method end to end

FRAMES = (0, 2, 4)
"""The walk's photos sent as the track (the others are the map's references)."""


@pytest.fixture(scope="module")
def walk_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("track-walk")
    options = WorldOptions(n_references=6, n_queries=1, seed=2, capture="walk", width=480, height=360)
    generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), out, options)
    return out


def _error_m(frame: Any, truth: dict[str, Any]) -> float:
    north_m = (frame.lat - truth["lat"]) * 111_132.0
    east_m = (frame.lon - truth["lon"]) * 111_320.0 * math.cos(math.radians(truth["lat"]))
    return math.hypot(north_m, east_m)


def _query_photos(data_dir: Path) -> list[str]:
    return [name for name in stored_files(data_dir) if name.startswith("queries/")]


def test_a_walk_is_located_as_a_track(tmp_path: Path, built_models: Path, walk_dir: Path, profile: Profile) -> None:
    world = load_world(walk_dir)
    photos = sorted(world.references, key=lambda im: im.name)
    track_photos = [photos[i] for i in FRAMES]
    data_dir = tmp_path / "data"
    with (
        running_service(data_dir, workers=2, models=built_models, **profile.new_env()) as service,
        Client(str(service.base_url), WRITE_KEY, timeout_s=300.0) as client,
    ):
        osm = shared_path("data", "osm", "helsinki.osm.pbf")
        map_id = client.upload_map(osm, "helsinki").id
        refs = [client.upload_reference(map_id, im.path).id for i, im in enumerate(photos) if i not in FRAMES]
        for ref in refs:
            assert client.wait_for_reference(ref, timeout_s=300).status == "done"

        t0 = time.perf_counter()
        track = client.upload_track(map_id, [im.path for im in track_photos], wait_s=300)
        seconds = time.perf_counter() - t0
        assert track.status == "done", track
        print(f"\n{len(FRAMES)}-frame track answered in {seconds:.1f} s end to end ({profile.name})")
        assert [f.index for f in track.frames] == [0, 1, 2]
        assert [f.original_filename for f in track.frames] == [im.path.name for im in track_photos]
        for frame, image in zip(track.frames, track_photos, strict=True):
            assert frame.lat is not None and frame.heading_deg is not None
            assert frame.source in ("track", "anchors", "likelihood")  # track: placed jointly with its neighbours
            assert frame.uncertainty_radius_m is not None and frame.uncertainty_radius_m > 0
            assert frame.capture_time is not None and frame.capture_time.startswith("20")
            assert _error_m(frame, image.record["pose"]) < 100.0, (frame, image.record["pose"])
            query = client.get_query(frame.query_id)
            assert query.status == "done" and query.result is not None
            best = query.result.locations[0]
            assert (best.lat, best.lon, best.heading_deg, best.source) == (
                frame.lat,
                frame.lon,
                frame.heading_deg,
                frame.source,
            )
            assert [b.building_id for b in frame.buildings] == [b.building_id for b in query.result.buildings]
        assert track.search is not None and track.search.smoother == "gtsam" and track.timings_ms is not None

        geojson = client.get_track_geojson(track.id)
        kinds = [f.properties["feature_type"] for f in geojson.features]
        assert kinds.count("trajectory") == 1 and kinds.count("frame") == 3 and kinds.count("view_cone") == 3
        line = next(f for f in geojson.features if f.properties["feature_type"] == "trajectory")
        assert line.geometry["type"] == "LineString"
        assert line.geometry["coordinates"] == [[f.lon, f.lat] for f in track.frames]
        assert geojson.member("attribution") and geojson.member("track_id") == track.id

        async def read_async() -> Any:
            async with AsyncClient(str(service.base_url), api_key=WRITE_KEY) as aclient:
                return await aclient.wait_for_track(track.id, timeout_s=30)

        assert asyncio.run(read_async()).frames == track.frames

        # The same photos again as earlier queries, sent newest first and ordered by capture time.
        reversed_ids = [f.query_id for f in reversed(track.frames)]
        again = client.track_of_queries(map_id, reversed_ids, by_capture_time=True, wait_s=300)
        assert again.status == "done", again
        assert [f.original_filename for f in again.frames] == [im.path.name for im in track_photos]
        assert {f.query_id for f in again.frames}.isdisjoint(reversed_ids)  # new frame rows; the queries stay

        # The CLI against the running service.
        cli = subprocess.run(
            [*geoloc_command(), "locate-track", str(track_photos[2].path), str(track_photos[0].path)]
            + ["--map", str(map_id), "--url", str(service.base_url), "--key", WRITE_KEY, "--json"],
            check=False,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert cli.returncode == 0, cli.stderr
        printed = json.loads(cli.stdout)
        assert printed["status"] == "done"
        assert [f["original_filename"] for f in printed["frames"]] == [
            track_photos[2].path.name,
            track_photos[0].path.name,
        ]

        # Deletion: a track goes with its frames; a photo another track still uses stays until that one goes.
        photos_before = _query_photos(data_dir)
        client.delete_track(track.id)
        assert client.get_query(again.frames[0].query_id).status == "done"
        assert _query_photos(data_dir) == photos_before
        client.delete_track(again.id)
        client.delete_track(printed["id"])
        assert _query_photos(data_dir) == []
