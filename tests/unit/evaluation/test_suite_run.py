"""The suite end to end on two tiny worlds: rendered once, evaluated by this checkout and by HEAD, figures and pairs."""

from __future__ import annotations

from pathlib import Path

import pytest

from geoloc.evaluation.suite.run import run_suite
from geoloc.evaluation.suite.trees import REPO_ROOT, export_commit, tree_fingerprint
from tests.model_fixtures import data_dir_environment

pytestmark = pytest.mark.slow  # the real method on two small worlds, twice: about two minutes

TINY = """
version = 1
[defaults]
references = 6
queries = 3
radius_m = 70.0
query_tracks = 2
track_length = 3
[maps]
village = "osm/germany_patch.osm"
[[worlds]]
name = "tiny-walk"
split = "dev"
capture = "walk"
map = "village"
form = "sparse_detached"
centre = [48.135792, 10.070294]
seed = 5
[[worlds]]
name = "tiny-tracks"
split = "dev"
capture = "tracks"
map = "village"
form = "sparse_detached"
centre = [48.135792, 10.070294]
seed = 6
"""


def test_the_suite_against_its_own_commit_differs_by_exactly_zero(built_models: Path, tmp_path: Path) -> None:
    head = tmp_path / "head"
    export_commit("HEAD", head)
    if tree_fingerprint(head) != tree_fingerprint(REPO_ROOT):
        pytest.skip("the working tree's method differs from HEAD's (uncommitted changes): nothing to pair")
    toml = tmp_path / "worlds.toml"
    toml.write_text(TINY)
    stages: dict[str, int] = {}

    def progress(what: str, done: int, total: int) -> None:
        stages[what] = total

    with data_dir_environment(built_models.parent.parent):
        run = run_suite("dev", cache=tmp_path / "cache", jobs=2, fresh=True, baseline="HEAD", progress=progress,
                        worlds_toml=toml)  # fmt: skip
        assert stages == {"render": 2, "evaluate": 2, "baseline": 2}
        report = run.report
        pooled = report["figures"]["pooled"]
        for name in ("queries.within_5m", "queries.gps_median_m", "references.sigma2_holds", "track_frames.within_5m"):
            assert pooled[name]["value"] is not None, name
        assert report["figures"]["world:tiny-walk"]["queries.within_5m"]["items"] == 3
        assert report["figures"]["capture:tracks"]["track_frames.within_5m"]["items"] == 6
        differences = [d for group in report["paired"].values() for d in group.values()]
        assert len(differences) > 50
        for difference in differences:
            assert (difference["value"], difference["low"], difference["high"]) == (0.0, 0.0, 0.0), difference

        again = run_suite("dev", cache=tmp_path / "cache", jobs=2, progress=progress, worlds_toml=toml)
        assert stages["render"] == 0 and stages["evaluate"] == 0  # both read from the cache
        assert again.report["figures"] == report["figures"]
