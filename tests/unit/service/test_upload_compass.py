"""An upload's priors: the photo's compass with its accuracy, its GPS fix's radius from its stated accuracy."""

from __future__ import annotations

import json
from pathlib import Path
from typing import cast

import pytest

from contracts.queries import DEFAULT_PRIOR_RADIUS_M, MIN_GPS_PRIOR_RADIUS_M, PriorPosition, gps_prior_radius_m
from contracts.settings import get_settings, shared_path
from db.files import FileStore
from db.rows import MapRow
from geoloc.photos.capture import DECLINATION_BOUND_DEG
from geoloc.photos.heading_prior import DEFAULT_SIGMA_DEG
from geoloc.photos.photo import load_photo
from service.images import ImageInfo, validate_image
from service.intake_queries import QueryForm, QueryIntake
from tests.service_fixtures import jpeg_bytes
from workers.broker import JobPublisher


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


def test_the_exif_prior_radius_comes_from_the_stated_gps_accuracy(tmp_path: Path) -> None:
    stated = json.dumps({"MAPGPSAccuracyMeters": "6.000000"})
    with_accuracy = _validated(tmp_path, jpeg_bytes(gps=(60.17, 24.94), description=stated))
    assert with_accuracy.gps_accuracy_m == 6.0
    assert _validated(tmp_path, jpeg_bytes(description=stated)).gps_accuracy_m is None  # no fix: no accuracy
    plain = _validated(tmp_path, jpeg_bytes(gps=(60.17, 24.94)))
    map_row = cast(MapRow, {"id": 1, "bbox_wgs84": (60.16, 24.93, 60.18, 24.95)})

    def prior(info: ImageInfo, radius_m: float | None = None) -> PriorPosition:
        form = QueryForm(None, None, radius_m, None, True, None, None, 10, 4, 0.0)
        intake = QueryIntake(get_settings(), cast(FileStore, None), cast(JobPublisher, None), form)
        intake.check_photo(map_row, info)
        assert intake.prior is not None and intake.prior.source == "exif"
        return intake.prior

    assert prior(with_accuracy).radius_m == gps_prior_radius_m(6.0) == 12.0  # twice the stated accuracy
    assert prior(with_accuracy).gps_accuracy_m == 6.0  # the answer's params say where the radius came from
    assert prior(with_accuracy, 30.0).radius_m == 30.0  # the request's radius wins
    assert "gps_accuracy_m" not in prior(with_accuracy, 30.0).model_dump(exclude_unset=True)
    assert prior(plain).radius_m == DEFAULT_PRIOR_RADIUS_M == 50.0
    assert "gps_accuracy_m" not in prior(plain).model_dump(exclude_unset=True)  # stored as before
    assert gps_prior_radius_m(2.0) == MIN_GPS_PRIOR_RADIUS_M  # no device is believed to the metre
