"""``geoloc eval world`` on a small walk world with query tracks: the track stage beside the frames alone."""

from __future__ import annotations

from pathlib import Path

import pytest

from contracts.settings import shared_path
from geoloc.evaluation.tracks import track_summary_lines
from geoloc.evaluation.world import default_runs, evaluate_world
from geoloc.localize.query import QueryConfig
from geoloc.sim.world import WorldOptions, generate_world
from workers.context import method_context

pytestmark = pytest.mark.slow  # the real method end to end: minutes


def test_a_world_with_only_tracks_reports_tracks_alone_and_the_injection(tmp_path: Path) -> None:
    opts = WorldOptions(
        n_references=8, n_queries=0, seed=1, capture="walk", radius_m=120.0, query_tracks=2, track_length=4
    )
    generate_world(shared_path("data", "osm", "helsinki.osm.pbf"), tmp_path / "w", opts)
    config = QueryConfig()
    runs = [run for run in default_runs(config) if run.name == "ours/gps"]
    result = evaluate_world(tmp_path / "w", config=config, runs=runs, context=method_context(), track_outliers=True)
    assert result["queries"] == 0 and result["runs"] == {}  # --queries 0: the track frames are no single queries
    tracks = result["tracks"]
    assert tracks["n_tracks"] == 2 and tracks["frames"] == 8
    for prior in ("gps", "none"):
        run = tracks[prior]
        assert run["track"]["n"] == run["alone"]["n"] == 8 and set(run["per_track"]) == {"0", "1"}
        assert 0.0 <= run["track"]["within_1m"] <= run["track"]["within_5m"] <= run["track"]["within_10m"] <= 1.0
        assert run["seconds_per_track"]["median"] > 0.0
        rows = run["per_frame"]
        assert [(r["track"], r["index"]) for r in rows] == [(t, k) for t in range(2) for k in range(4)]
        assert not any(r["replaced"] for r in rows)
        # A frame the track joined answers with the track's pose; one it did not keeps its own answer.
        for r in rows:
            assert r["source"] in ("track", "anchors", "likelihood")
            if r["source"] != "track":
                assert r["error_m"] == r["alone_error_m"]
    injection = tracks["outlier_injection"]
    replaced = [r for r in injection["per_frame"] if r["replaced"]]
    assert [(r["track"], r["index"]) for r in replaced] == [(0, 2), (1, 2)]
    assert replaced[0]["name"] == "track_01_02" and replaced[1]["name"] == "track_00_02"
    assert injection["others"]["n"] == 6 and injection["replaced_flagged"] is not None
    assert any("outlier injection" in line for line in track_summary_lines(tracks))
