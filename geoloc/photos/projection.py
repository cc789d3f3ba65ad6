r"""Which projection a photo is in: an ordinary perspective photo, or a panorama (equirectangular, ...).

The method models one pinhole camera (:mod:`geoloc.core.camera`); a 360-degree panorama is not one, so the
service refuses it (:func:`service.images.validate_image`) until the method supports it. Told by:

1. the photo's XMP: Google's photo-sphere metadata ``GPano:ProjectionType`` (``"equirectangular"`` from
   every 360-degree camera and stitcher; ``"cylindrical"`` and others from some), as an attribute
   (``GPano:ProjectionType="equirectangular"``) or an element
   (``<GPano:ProjectionType>equirectangular</GPano:ProjectionType>``). The XMP packet is plain text (a JPEG's
   APP1 segment after ``http://ns.adobe.com/xap/1.0/\x00``, a PNG's iTXt, a WEBP's ``XMP`` chunk, a TIFF's
   tag 700), so a bounded byte search of the file's first :data:`XMP_SEARCH_BYTES` finds it: no XMP parser;
2. without one: a 2:1 image (within :data:`ASPECT_TOLERANCE`) that shows a full horizontal field of view:
   360 degrees across by 180 down is exactly 2:1, and nothing in the photo says it came through a lens of
   a perspective camera (no EXIF focal length). A 2:1 phone photo (18:9 modes) carries its focal length
   and stays a perspective photo.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

XMP_SEARCH_BYTES = 256 * 1024
"""How far into the file the XMP packet is looked for (cameras write it in the first few KiB)."""
ASPECT_TOLERANCE = 0.01
"""Relative tolerance of the 2:1 aspect of an equirectangular image without XMP (a pixel of rounding)."""

_PROJECTION = re.compile(
    rb"(?i)GPano:ProjectionType\s*=\s*[\"']\s*([A-Za-z_-]{1,40})\s*[\"']"
    rb"|<GPano:ProjectionType>\s*([A-Za-z_-]{1,40})\s*</GPano:ProjectionType>"
)

ProjectionSource = Literal["xmp", "aspect"]


@dataclass(frozen=True)
class Projection:
    """A photo's projection when it is not a perspective one.

    name: the projection (lower case, ``"equirectangular"``...). source: ``"xmp"`` (``GPano:ProjectionType``)
    or ``"aspect"`` (2:1 with a full horizontal field of view). evidence: what told it, in words.
    """

    name: str
    source: ProjectionSource
    evidence: str


def xmp_projection(head: bytes) -> str | None:
    """``GPano:ProjectionType`` (lower case) in the first :data:`XMP_SEARCH_BYTES` of a file, None without."""
    match = _PROJECTION.search(head[:XMP_SEARCH_BYTES])
    if match is None:
        return None
    return (match.group(1) or match.group(2)).decode("ascii").lower()


def is_full_sphere_aspect(width: int, height: int) -> bool:
    """Whether ``width`` x ``height`` is 2:1 (360 by 180 degrees), within :data:`ASPECT_TOLERANCE`."""
    return height > 0 and abs(width / (2.0 * height) - 1.0) <= ASPECT_TOLERANCE


def photo_projection(head: bytes, width: int, height: int, *, has_focal_length: bool) -> Projection | None:
    """The projection of a photo that is not a perspective one, None for an ordinary photo (module doc).

    head: the file's first bytes (at least :data:`XMP_SEARCH_BYTES`, or the whole file); width, height: its
    pixel size; has_focal_length: whether its EXIF states a focal length (a lens of a perspective camera).
    """
    stated = xmp_projection(head)
    if stated is not None and stated != "perspective":
        return Projection(stated, "xmp", f'XMP GPano:ProjectionType="{stated}"')
    if stated is None and not has_focal_length and is_full_sphere_aspect(width, height):
        return Projection(
            "equirectangular", "aspect", f"a 2:1 image ({width}x{height}) with no focal length: a full 360-degree view"
        )
    return None


def read_head(path: Path) -> bytes:
    """The first :data:`XMP_SEARCH_BYTES` of a file."""
    with path.open("rb") as f:
        return f.read(XMP_SEARCH_BYTES)
