"""One photo loader: the API, the workers and ``geoloc analyze`` see the same pixels and the same EXIF.

The API checks an upload (:func:`service.images.validate_image`) and stores it; a worker reads the stored file
(:func:`workers.handler_helpers.stored_photo`); ``geoloc analyze`` reads a file (:func:`cli.analyze.read_photo`).
All go through :func:`geoloc.photos.photo.load_photo` / :func:`geoloc.photos.exif.read_exif`.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cli.analyze import read_photo
from contracts.settings import get_settings, reset_settings
from db.files import open_store
from geoloc.photos.exif import ExifFields, exif_bytes
from geoloc.photos.photo import WORKING_MAX_SIDE, load_photo
from service.images import validate_image
from workers.handler_helpers import stored_photo

ORIENTATION_TAG = 0x0112


def _pixels(width: int, height: int) -> np.ndarray:
    rng = np.random.default_rng(4)
    rgb = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    rgb[: height // 4, : width // 3] = (250, 20, 20)  # a corner that shows where the rotation put it
    return rgb


@pytest.fixture
def store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    monkeypatch.setenv("GEOLOC_DATA_DIR", str(tmp_path / "data"))
    reset_settings()
    yield get_settings().file_store_dir
    reset_settings()


def _jpeg_rotated_with_gps(path: Path) -> Path:
    """A 1600 x 1200 JPEG stored sideways (EXIF orientation 6), with GPS, heading and focal length."""
    block = exif_bytes(1600, 1200, ExifFields(lat=60.1699, lon=24.9384, focal_35mm=28.0, heading_deg=123.5))
    exif = Image.Exif()
    exif.load(block)
    exif[ORIENTATION_TAG] = 6
    Image.fromarray(_pixels(1600, 1200)).save(path, "JPEG", quality=92, exif=exif.tobytes())
    return path


def _png(path: Path) -> Path:
    Image.fromarray(_pixels(900, 700)).save(path, "PNG")
    return path


@pytest.mark.parametrize("make", [_jpeg_rotated_with_gps, _png])
def test_the_three_paths_see_the_same_photo(make: Callable[[Path], Path], tmp_path: Path, store: Path) -> None:
    path = make(tmp_path / "photo.bin")
    reference = load_photo(path)

    # The API: its header checks and its EXIF.
    info = validate_image(path, max_pixels=50_000_000, min_side=64)
    assert (info.gps_lat, info.gps_lon) == ((reference.exif.lat, reference.exif.lon) if reference.gps else (None, None))
    assert info.focal_length_35mm == reference.exif.focal_35mm
    compass = reference.capture.compass
    assert info.heading_deg == (None if compass is None else compass.heading_deg)

    # The workers: the stored upload, read back for a job.
    upload = tmp_path / "upload.bin"
    shutil.copyfile(path, upload)
    open_store(store).put(upload, "uploads/photo.bin")  # the API moves the upload into the store
    stored = stored_photo("uploads/photo.bin", info.focal_length_35mm)
    np.testing.assert_array_equal(stored.image_rgb, reference.image_rgb)
    assert stored.exif == reference.exif and stored.intrinsics == reference.intrinsics

    # `geoloc analyze`: the same pixels and intrinsics (it used to skip the working-size resize).
    cli = read_photo(path)
    np.testing.assert_array_equal(cli.image_rgb, reference.image_rgb)
    assert cli.exif == reference.exif and cli.intrinsics == reference.intrinsics
    assert max(cli.image_rgb.shape[:2]) <= WORKING_MAX_SIDE


def test_the_photo_is_upright_with_its_exif(tmp_path: Path) -> None:
    photo = load_photo(_jpeg_rotated_with_gps(tmp_path / "rotated.jpg"))
    assert photo.original_size == (1200, 1600)  # orientation 6: stored landscape, shown portrait
    assert photo.image_rgb.shape == (1024, 768, 3)
    assert photo.gps == pytest.approx((60.1699, 24.9384), abs=1e-6)
    assert photo.exif.heading_deg == pytest.approx(123.5) and photo.exif.focal_35mm == 28.0
    assert photo.intrinsics.source != "default"
    red = photo.image_rgb[..., 0].astype(int) - photo.image_rgb[..., 1].astype(int) > 150
    rows, cols = np.nonzero(red)
    assert cols.min() > 768 // 2 and rows.max() < 1024 // 2  # the top-left corner turned to the top right


def test_analyze_keeps_its_field_of_view_override(tmp_path: Path) -> None:
    photo = read_photo(_jpeg_rotated_with_gps(tmp_path / "rotated.jpg"), hfov_deg=70.0)
    assert photo.intrinsics.source == "given" and photo.intrinsics.hfov_deg == pytest.approx(70.0)
    assert (photo.intrinsics.width, photo.intrinsics.height) == (768, 1024)
