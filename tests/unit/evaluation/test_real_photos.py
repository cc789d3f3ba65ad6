"""Real phone photos labelled on a real map, as the service labels references (``geoloc eval photos``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from contracts.settings import shared_path
from geoloc.evaluation.world import evaluate_photos
from tests.model_fixtures import data_dir_environment
from workers.context import method_context

pytestmark = pytest.mark.slow  # the segmentation network on three 8 MP photos


@pytest.mark.parametrize("as_the_service", [False, True], ids=["map-alone", "compass-and-walk"])
def test_berlin_photos_get_their_compass_heading_and_the_building(built_models: Path, as_the_service: bool) -> None:
    """The map alone, and as the service labels references: the compass as a prior, the walk placed jointly."""
    berlin = shared_path("data", "berlin")
    with data_dir_environment(built_models.parent.parent):
        osm, truth = berlin / "berlin_mitte.osm.gz", berlin / "exif_gps_heading.csv"
        result = evaluate_photos(
            berlin / "images",
            osm,
            truth,
            compass_prior=as_the_service,
            place_walks=as_the_service,
            context=method_context(),
        )
    assert result["walks"] == ([3] if as_the_service else [])  # one Mapillary sequence
    rows = {row["name"]: row for row in result["photos"]}
    assert sorted(rows) == ["01.jpg", "02.jpg", "03.jpg"]
    for row in rows.values():
        # The phone's compass is good to about 10 degrees (its own accuracy field says so).
        assert row["heading_error_deg"] <= 10.0, row
        assert "Berliner Dom" in row["buildings"], row
        assert row["moved_m"] < 15.0  # labelling corrects the GPS tag by metres, not streets
    assert result["heading_within_10deg"] == 1.0
