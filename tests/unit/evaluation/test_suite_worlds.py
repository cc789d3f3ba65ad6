"""The suite's declared worlds: both splits' size and mix, the list printed without rendering, content keys."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from contracts.settings import shared_path
from geoloc.evaluation.suite.worlds import FORMS, load_suite, world_key

SUITE = load_suite()


@pytest.mark.parametrize("split", ["dev", "test"])
def test_each_split_has_its_walk_scattered_and_track_worlds_over_every_map(split: str) -> None:
    worlds = SUITE.split(split)
    captures = Counter(w.capture for w in worlds)
    assert captures["walk"] >= 16 and captures["scattered"] >= 4 and captures["tracks"] >= 4
    assert {w.map_file for w in worlds} == {m for m in (w.map_file for w in SUITE.worlds)}
    assert len({w.map_file for w in worlds}) == 4
    assert {w.form for w in worlds} == set(FORMS)
    for world in worlds:
        assert shared_path("data", *world.map_file.split("/")).is_file(), world.map_file


def test_the_splits_have_the_same_size_and_mix_and_other_seeds_and_centres() -> None:
    dev, test = SUITE.split("dev"), SUITE.split("test")
    assert Counter((w.capture, w.form, w.map_file) for w in dev) == Counter(
        (w.capture, w.form, w.map_file) for w in test
    )
    assert not {w.seed for w in dev} & {w.seed for w in test}
    assert not {(w.map_file, w.centre_wgs84) for w in dev} & {(w.map_file, w.centre_wgs84) for w in test}


def test_list_json_prints_every_world_without_rendering(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["eval", "suite", "--split", "test", "--list", "--json", "--cache", str(tmp_path)])
    assert result.exit_code == 0, result.output
    listed = json.loads(result.stdout)
    assert len(listed) == len(SUITE.split("test"))
    for world in listed:
        assert {"name", "map", "centre_wgs84", "seed", "capture", "form"} <= set(world)
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_split_or_form_is_refused_with_the_reason(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["eval", "suite", "--split", "train", "--list"])
    assert result.exit_code == 2 and "dev, test" in result.output
    toml = tmp_path / "worlds.toml"
    toml.write_text(
        '[maps]\nm = "osm/germany_patch.osm"\n[[worlds]]\nname = "w"\nsplit = "dev"\ncapture = "walk"\nmap = "m"\n'
        'form = "suburbia"\ncentre = [48.1, 10.0]\nseed = 1\nreferences = 4\nqueries = 2\nradius_m = 50.0\n'
        "query_tracks = 0\ntrack_length = 3\n"
    )
    with pytest.raises(ValueError, match="world w: form"):
        load_suite(toml)


def test_the_content_key_follows_the_options_not_the_labels() -> None:
    world = SUITE.split("dev")[0]
    path = shared_path("data", *world.map_file.split("/"))
    key = world_key(world, path, generator="g")
    assert world_key(replace(world, name="other", form="waterfront", split="test"), path, "g") == key
    assert world_key(replace(world, seed=world.seed + 1), path, "g") != key
    assert world_key(world, path, generator="h") != key
