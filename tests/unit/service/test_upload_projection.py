"""A panorama is refused at the one check every photo upload passes (references, queries, tracks): 422.

The same refusal through a running service (nothing stored, as a reference and as a query, and in
``geoloc ingest``'s summary) is in ``tests/e2e/test_ingest.py``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from service.errors import ApiError
from service.images import validate_image
from tests.service_fixtures import jpeg_bytes, panorama_jpeg_bytes


@pytest.mark.parametrize("xmp", ["attribute", "element", None])
def test_an_equirectangular_photo_is_a_422_naming_the_projection_and_what_is_supported(
    tmp_path: Path, xmp: str | None
) -> None:
    path = tmp_path / "upload-0123abcd.part"
    path.write_bytes(panorama_jpeg_bytes(xmp=xmp, gps=(60.1716, 24.9443)))
    with pytest.raises(ApiError) as caught:
        validate_image(path, max_pixels=50_000_000, min_side=64)
    error = caught.value
    assert (error.status, error.code) == (422, "unsupported_projection")
    assert "equirectangular panorama" in error.message and "perspective photos" in error.message
    assert error.details == {
        "projection": "equirectangular",
        "source": "xmp" if xmp else "aspect",
        "supported": ["perspective"],
    }
    assert str(tmp_path) not in error.message and ".part" not in error.message, "no server path"
    assert "Traceback" not in error.message


def test_a_2_to_1_photo_with_a_focal_length_is_an_ordinary_photo(tmp_path: Path) -> None:
    path = tmp_path / "wide.jpg"
    path.write_bytes(jpeg_bytes(1024, 512))  # 28 mm in EXIF: an 18:9 phone photo
    info = validate_image(path, max_pixels=50_000_000, min_side=64)
    assert (info.width, info.height, info.focal_length_35mm) == (1024, 512, 28.0)
