"""The one photo loader: a JPEG/PNG/WebP/TIFF/HEIC (bytes or a path) -> pixels at working size, EXIF, intrinsics.

The API (checking an upload), the workers (answering a job) and the command line (``geoloc analyze``,
``geoloc eval``) all read photos through :func:`load_photo`, so they see the same pixels and the same EXIF.
It applies the EXIF orientation, reads GPS, heading and focal length (:mod:`geoloc.photos.exif`) and the
capture's time, walk and compass (:mod:`geoloc.photos.capture`), resizes to
at most :data:`WORKING_MAX_SIDE` pixels on the long side and derives the intrinsics of that image.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

from geoloc.core.camera import DEFAULT_HFOV_DEG, Intrinsics, intrinsics_from_focal
from geoloc.photos.capture import CaptureInfo, capture_of
from geoloc.photos.exif import ExifInfo, exif_info, load_exif

WORKING_MAX_SIDE = 1024
"""Photos are analysed at most this many pixels on their long side (phone photos are 3-12 MP)."""


@dataclass
class Photo:
    """A decoded photo at working size. image_rgb: (H, W, 3) uint8; intrinsics of that image."""

    image_rgb: np.ndarray
    intrinsics: Intrinsics
    exif: ExifInfo
    original_size: tuple[int, int]  # (width, height) after EXIF orientation, before resizing
    capture: CaptureInfo = field(default_factory=CaptureInfo)
    """Capture time, walk (sequence id) and compass (:mod:`geoloc.photos.capture`); not yet used by the method."""

    @property
    def gps(self) -> tuple[float, float] | None:
        """(lat, lon) degrees from EXIF, or None when the photo carries no GPS."""
        lat, lon = self.exif.lat, self.exif.lon
        return None if lat is None or lon is None else (lat, lon)


def load_photo(
    source: bytes | str | Path,
    *,
    focal_35mm: float | None = None,
    default_hfov_deg: float = DEFAULT_HFOV_DEG,
    max_side: int = WORKING_MAX_SIDE,
) -> Photo:
    """Decode a photo (bytes or path) for analysis.

    ``focal_35mm`` overrides the EXIF focal length. Raises ``ValueError`` for data that is not an
    image Pillow can decode.
    """
    data = source if isinstance(source, bytes) else Path(source).read_bytes()
    try:
        image: Image.Image = Image.open(io.BytesIO(data))
        image.load()
    except Exception as exc:  # Pillow raises many types for bad data
        raise ValueError(f"not a decodable image: {exc}") from exc
    block = load_exif(data)  # parsed once for both readings
    exif = exif_info(block)
    image = ImageOps.exif_transpose(image).convert("RGB")
    width, height = image.size
    intrinsics = intrinsics_from_focal(
        width,
        height,
        focal_35mm=focal_35mm or exif.focal_35mm,
        default_hfov_deg=default_hfov_deg,
    )
    scale = min(1.0, max_side / max(width, height))
    if scale < 1.0:
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        image = image.resize(size, Image.Resampling.LANCZOS)
        intrinsics = intrinsics.scaled(*size)
    return Photo(np.asarray(image), intrinsics, exif, (width, height), capture_of(block))
