"""Query tracks (``--query-tracks N --track-length L``): walks of query photos 3-8 m apart, on real OSM maps."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.maps import load_map
from geoloc.sim import Scene
from geoloc.sim.sampling import world_centre
from geoloc.sim.tracks import TRACK_STEP_M, sample_tracks
from geoloc.sim.walks import COMPASS_SHARE
from geoloc.sim.world import WorldOptions, generate_world, load_world

HELSINKI = shared_path("data", "osm", "helsinki.osm.pbf")
PATCH = shared_path("data", "osm", "germany_patch.osm")


def test_tracks_have_their_length_frames_3_to_8_m_apart_with_correlated_gps() -> None:
    city = load_map(HELSINKI)
    opts = WorldOptions(seed=1, query_tracks=8, track_length=10)
    shots, walks = sample_tracks(Scene(city, seed=1), opts, world_centre(city))
    assert len(walks) == 8 and len(shots) == 80
    steps, gps_steps, compass = [], [], []
    for t in range(8):
        track = [s for s in shots if s.walk_id == t]
        assert [s.index for s in track] == list(range(10))
        xy = np.array([[s.pose.x_m, s.pose.y_m] for s in track])
        steps += list(np.hypot(*np.diff(xy, axis=0).T))
        offsets = np.array([s.gps_offset_m for s in track])
        gps_steps += list(np.hypot(*np.diff(offsets, axis=0).T) / max(float(np.hypot(*offsets.T).mean()), 1e-6))
        compass += [s.compass_error_deg is not None for s in track]
        times = [s.capture_time for s in track]
        assert times == sorted(times)
    assert min(steps) >= TRACK_STEP_M[0] - 1e-6 and max(steps) <= TRACK_STEP_M[1] + 1e-6
    assert np.median(gps_steps) < 0.6  # the offset moves little from one frame to the next: correlated
    assert abs(float(np.mean(compass)) - COMPASS_SHARE) < 0.12


def test_a_world_with_tracks_and_no_queries_marks_each_frame(tmp_path: Path) -> None:
    city = load_map(PATCH)
    opts = WorldOptions(
        n_references=3, n_queries=0, seed=2, width=160, height=120, radius_m=0.0, query_tracks=2, track_length=4
    )
    m1 = generate_world(PATCH, tmp_path / "w1", opts, city_map=city)
    m2 = generate_world(PATCH, tmp_path / "w2", opts, city_map=city)
    assert m1["images"] == m2["images"]
    assert m1["options"]["query_tracks"] == 2 and m1["options"]["track_length"] == 4
    world = load_world(tmp_path / "w1")
    frames = world.queries
    assert len(frames) == 8 and all(im.record["kind"] == "track" for im in frames)
    assert [(im.record["track"], im.record["index"]) for im in frames] == [(t, k) for t in range(2) for k in range(4)]
    for im in frames:
        assert im.path.exists() and im.name == f"track_{im.record['track']:02d}_{im.record['index']:02d}"
        gps = im.record["gps"]
        assert gps["model"] == "walk_ar1" and math.hypot(gps["noise_east_m"], gps["noise_north_m"]) < 80.0
        assert "compass" in im.record and "walk" not in im.record


def test_a_world_without_tracks_records_no_track_options(tmp_path: Path) -> None:
    city = load_map(PATCH)
    opts = WorldOptions(n_references=2, n_queries=1, seed=2, width=96, height=72, radius_m=0.0)
    manifest = generate_world(PATCH, tmp_path / "w", opts, city_map=city)
    assert "query_tracks" not in manifest["options"] and "track_length" not in manifest["options"]
    assert not any("track" in im for im in manifest["images"])


@pytest.mark.parametrize("length", [2, 5])
def test_track_length_is_respected_on_a_small_map(length: int) -> None:
    city = load_map(PATCH)
    shots, walks = sample_tracks(
        Scene(city, seed=3), WorldOptions(seed=3, radius_m=0.0, query_tracks=1, track_length=length), world_centre(city)
    )
    assert len(walks) == 1 and [s.index for s in shots] == list(range(length))
