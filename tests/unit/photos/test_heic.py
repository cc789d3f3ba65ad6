"""HEIC/HEIF photos (iPhones' default): the one loader and the upload check read them as their JPEG twins."""

from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image

from contracts.settings import shared_path
from geoloc.photos.photo import load_photo
from service.errors import ApiError
from service.images import validate_image
from tests.service_fixtures import phone_photo_twins

BERLIN_PHOTO = shared_path("data", "berlin", "images", "01.jpg")
pytestmark = pytest.mark.skipif(not BERLIN_PHOTO.is_file(), reason="needs shared/data/berlin")


@pytest.fixture(scope="module")
def twins() -> tuple[bytes, bytes]:
    return phone_photo_twins(BERLIN_PHOTO)


def test_heic_is_really_heic(twins: tuple[bytes, bytes]) -> None:
    _, heic = twins
    assert heic[4:12] == b"ftypheic"


def test_the_loader_reads_gps_heading_and_focal_length_from_a_heic_as_from_its_jpeg(
    twins: tuple[bytes, bytes],
) -> None:
    jpeg, heic = (load_photo(data) for data in twins)
    assert heic.gps == jpeg.gps and heic.gps == pytest.approx((52.518916667, 13.400294444), abs=1e-6)
    assert heic.exif.focal_35mm == jpeg.exif.focal_35mm and heic.exif.focal_35mm is not None
    assert heic.exif.heading_deg == jpeg.exif.heading_deg
    assert heic.capture.compass == jpeg.capture.compass and heic.capture.compass is not None
    assert heic.capture.compass.heading_deg == pytest.approx(54.74463, abs=1e-4)  # the photo's TrueHeading
    assert heic.image_rgb.shape == jpeg.image_rgb.shape
    assert heic.intrinsics == jpeg.intrinsics


def test_the_upload_check_accepts_a_heic_with_the_same_facts(tmp_path: Path, twins: tuple[bytes, bytes]) -> None:
    infos = []
    for name, data in zip(("twin.jpg", "twin.heic"), twins, strict=True):
        path = tmp_path / name
        path.write_bytes(data)
        infos.append(validate_image(path, max_pixels=50_000_000, min_side=64))
    jpeg, heic = infos
    assert (heic.format, heic.extension) == ("HEIF", "heic")
    for field in ("width", "height", "gps_lat", "gps_lon", "focal_length_35mm", "heading_deg", "heading_accuracy_deg"):
        assert getattr(heic, field) == getattr(jpeg, field), field
    assert heic.gps_lat is not None and heic.heading_deg is not None


def test_a_heic_over_the_pixel_limit_is_refused_before_decoding(tmp_path: Path, twins: tuple[bytes, bytes]) -> None:
    path = tmp_path / "big.heic"
    path.write_bytes(twins[1])
    with pytest.raises(ApiError) as refused:
        validate_image(path, max_pixels=100_000, min_side=64)
    assert refused.value.status == 413 and refused.value.code == "too_many_pixels"


def test_the_decompression_bomb_guard_applies_to_heic(
    tmp_path: Path, twins: tuple[bytes, bytes], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Pillow's own bomb check (on the header's size, before decoding) runs for HEIC as for JPEG."""
    path = tmp_path / "bomb.heic"
    path.write_bytes(twins[1])
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100_000)  # the photo's 816 x 612 is over twice this: an error
    with pytest.raises(ApiError) as refused:
        validate_image(path, max_pixels=50_000_000, min_side=64)
    assert refused.value.status == 413 and "decompression bomb" in refused.value.message


@pytest.mark.parametrize("kept", [40, 2000, 0.5], ids=["in-ftyp", "in-meta", "in-coded-image"])
def test_a_corrupt_heic_gets_a_4xx_with_a_reason(tmp_path: Path, twins: tuple[bytes, bytes], kept: float) -> None:
    """The file cut short: in its header, its item boxes, or halfway through (the coded image).

    Not near its end: pillow-heif 1.9 writes the XMP after the coded image, and a HEIC cut there is whole.
    """
    heic = twins[1]
    path = tmp_path / "corrupt.heic"
    path.write_bytes(heic[: int(kept * len(heic)) if kept < 1 else int(kept)])
    with pytest.raises(ApiError) as refused:
        validate_image(path, max_pixels=50_000_000, min_side=64)
    assert 400 <= refused.value.status < 500 and refused.value.message
    assert str(tmp_path) not in refused.value.message


def test_geoloc_ingest_picks_a_heic_by_its_content(twins: tuple[bytes, bytes]) -> None:
    from cli.photo_files import sniff_photo  # the CLI's own check of a folder's files

    jpeg, heic = twins
    assert (sniff_photo(jpeg[:16]), sniff_photo(heic[:16])) == ("image/jpeg", "image/heic")
    assert sniff_photo(b"\x00\x00\x00\x1cftypisom\x00\x00") is None  # an MP4 is not a photo
