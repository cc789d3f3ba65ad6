"""The track benchmark's reading of a world (its query tracks, each frame in order with its truth) and summary."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks.eval_agreement import query_agreement, track_agreement
from benchmarks.track_checks import track_summary, world_tracks
from contracts.settings import shared_path
from geoloc.sim.world import WorldOptions, generate_world, load_world


def test_world_tracks_lists_each_track_in_frame_order_with_its_truth(tmp_path: Path) -> None:
    opts = WorldOptions(
        n_references=4, n_queries=1, seed=2, capture="walk", radius_m=100.0, query_tracks=2, track_length=3
    )
    generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), tmp_path, opts)
    tracks = world_tracks(load_world(tmp_path))
    manifest = {image["file"]: image for image in json.loads((tmp_path / "manifest.json").read_text())["images"]}
    assert sorted(tracks) == [0, 1] and all(len(frames) == 3 for frames in tracks.values())
    for track, frames in tracks.items():
        for index, (path, truth) in enumerate(frames):
            record = manifest[str(path.relative_to(tmp_path))]
            assert (record["track"], record["index"]) == (track, index)  # the single query is no track frame
            assert truth == (record["pose"]["lat"], record["pose"]["lon"])


def test_the_summary_counts_a_frame_without_a_pose_as_outside_and_judges_the_median() -> None:
    rows = [
        {"wall_s": 4.0, "errors_m": [0.5, 3.0]},
        {"wall_s": 7.0, "errors_m": [12.0, None]},
        {"wall_s": 5.0, "errors_m": []},
    ]
    summary = track_summary(rows)
    assert summary["wall_s_median"] == 5.0 and summary["wall_s_max"] == 7.0 and summary["passes"]
    assert (summary["frames"], summary["within_1m"], summary["within_5m"], summary["within_10m"]) == (4, 0.25, 0.5, 0.5)
    assert not track_summary(rows[1:2])["passes"]  # 7 s > 6 s


def test_agreement_with_the_evaluation_allows_the_wgs84_round_trip_and_no_more() -> None:
    tracks = {"0": {"errors_m": [1.0, 7.59, 300.0]}, "1": {"errors_m": [None, 2.0]}}
    per_frame = [
        {"track": 0, "index": 0, "error_m": 1.2},  # 0.2 m apart: the same answer measured in two frames
        {"track": 0, "index": 1, "error_m": 7.61},
        {"track": 0, "index": 2, "error_m": 305.0},  # 5 m at 300 m: within 2 %
        {"track": 1, "index": 0, "error_m": 3.0},  # the API answered nothing
        {"track": 1, "index": 1, "error_m": 2.5},  # 0.5 m apart: another answer
    ]
    agreement = track_agreement(tracks, {"tracks": {"gps": {"per_frame": per_frame}}})
    assert (agreement["photos"], agreement["same"]) == (5, 3)
    assert agreement["differ"] == [((1, 0), None, 3.0), ((1, 1), 2.0, 2.5)]
    queries = {"query_000": 4.0, "query_001": None, "query_002": 12.0, "track_00_00": 1.0}
    per_query = [{"name": "query_000", "error_m": 4.1}, {"name": "query_001", "error_m": 9.0}]
    per_query.append({"name": "query_002", "error_m": 11.0})
    single = query_agreement(queries, {"runs": {"ours/gps": {"per_query": per_query}}})
    assert (single["photos"], single["same"]) == (3, 1)  # a track frame is not a single query of the evaluation
    assert single["differ"] == [("query_001", None, 9.0), ("query_002", 12.0, 11.0)]
