"""An upload's heading prior: the photo's compass with its accuracy (:mod:`service.images`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from contracts.settings import shared_path
from geoloc.photos.capture import DECLINATION_BOUND_DEG
from geoloc.photos.heading_prior import DEFAULT_SIGMA_DEG
from geoloc.photos.photo import load_photo
from service.images import validate_image
from tests.service_fixtures import jpeg_bytes


def _validated(tmp_path: Path, data: bytes):
    path = tmp_path / "upload.jpg"
    path.write_bytes(data)
    return validate_image(path, max_pixels=50_000_000, min_side=64)


def test_a_real_mapillary_photo_gives_its_true_heading_and_accuracy() -> None:
    path = shared_path("data", "lund", "images", "01.jpg")
    if not path.is_file():
        pytest.skip("the Lund photos are not in the shared data")
    compass = load_photo(path).capture.compass
    assert compass is not None and compass.source == "mapillary" and compass.accuracy_deg is not None
    info = validate_image(path, max_pixels=50_000_000, min_side=64)
    assert (info.heading_deg, info.heading_accuracy_deg) == (compass.heading_deg, compass.accuracy_deg)


def test_exif_directions_magnetic_widened_true_without_accuracy_the_default(tmp_path: Path) -> None:
    magnetic = _validated(tmp_path, jpeg_bytes(direction=(200.0, "M")))
    assert magnetic.heading_deg == pytest.approx(200.0)  # was used as a true heading, unwidened: the "M" bug
    assert magnetic.heading_accuracy_deg == pytest.approx(DECLINATION_BOUND_DEG)
    true = _validated(tmp_path, jpeg_bytes(direction=(200.0, "T")))
    assert true.heading_deg == pytest.approx(200.0) and true.heading_accuracy_deg == DEFAULT_SIGMA_DEG
    none = _validated(tmp_path, jpeg_bytes())
    assert none.heading_deg is None and none.heading_accuracy_deg is None


def test_mapillary_json_wins_over_exif_direction(tmp_path: Path) -> None:
    description = json.dumps({"MAPCompassHeading": {"TrueHeading": 123.5, "AccuracyDegrees": 12.0}})
    info = _validated(tmp_path, jpeg_bytes(description=description, direction=(10.0, "T")))
    assert (info.heading_deg, info.heading_accuracy_deg) == (123.5, 12.0)
