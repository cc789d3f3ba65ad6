"""Which photos are panoramas: GPano XMP (attribute or element form), else a 2:1 shape without a lens."""

from __future__ import annotations

import pytest

from geoloc.photos.exif import read_exif
from geoloc.photos.projection import XMP_SEARCH_BYTES, photo_projection, xmp_projection
from tests.service_fixtures import jpeg_bytes, panorama_jpeg_bytes


@pytest.mark.parametrize("form", ["attribute", "element"])
def test_gpano_xmp_says_equirectangular(form: str) -> None:
    data = panorama_jpeg_bytes(xmp=form)
    assert xmp_projection(data) == "equirectangular"
    found = photo_projection(data, 1024, 512, has_focal_length=True)  # the XMP wins over a focal length
    assert found is not None and (found.name, found.source) == ("equirectangular", "xmp")
    assert 'GPano:ProjectionType="equirectangular"' in found.evidence


def test_a_2_to_1_image_without_xmp_is_equirectangular_only_without_a_focal_length() -> None:
    data = panorama_jpeg_bytes(xmp=None)
    assert xmp_projection(data) is None and read_exif(data).focal_35mm is None
    found = photo_projection(data, 1024, 512, has_focal_length=False)
    assert found is not None and (found.name, found.source) == ("equirectangular", "aspect")
    assert photo_projection(data, 1024, 513, has_focal_length=False) is not None, "a pixel of rounding"
    assert photo_projection(data, 1024, 512, has_focal_length=True) is None, "an 18:9 phone photo"
    assert photo_projection(data, 1024, 768, has_focal_length=False) is None, "4:3"


def test_ordinary_photos_and_xmp_past_the_search_window_are_perspective() -> None:
    assert photo_projection(jpeg_bytes(640, 480), 640, 480, has_focal_length=True) is None
    late = b"\x00" * XMP_SEARCH_BYTES + b'GPano:ProjectionType="equirectangular"'
    assert xmp_projection(late) is None, "the search is bounded"
    assert xmp_projection(b'<x GPano:ProjectionType = "Cylindrical" />') == "cylindrical"
