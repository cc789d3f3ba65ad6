"""Checking an uploaded photo by its content (Pillow), reading its EXIF (``geoloc.photos.exif``), serving it.

The heading prior of an upload without a form ``heading_deg`` is the photo's compass
(:func:`geoloc.photos.capture.read_capture`: Mapillary's JSON first, then EXIF ``GPSImgDirection``; a magnetic
heading is kept and its accuracy widened by the declination bound), stored with its accuracy so that the
worker weights it as a robust prior (:mod:`geoloc.photos.heading_prior`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

from fastapi.responses import FileResponse
from PIL import Image, UnidentifiedImageError

from geoloc.photos.capture import capture_of, photo_device
from geoloc.photos.exif import ExifInfo, exif_info, load_exif
from geoloc.photos.heading_prior import compass_accuracy_deg
from geoloc.photos.projection import photo_projection, read_head
from service.errors import ApiError

ACCEPTED_FORMATS = {"JPEG": "jpg", "MPO": "jpg", "PNG": "png", "WEBP": "webp", "TIFF": "tif", "HEIF": "heic"}
"""Pillow format -> stored file extension. MPO is how Pillow names multi-picture phone JPEGs; HEIF is HEIC/HEIF
(iPhones' default), opened through ``pillow-heif`` (registered by :mod:`geoloc.photos.exif`)."""
ACCEPTED_NAMES = "JPEG, PNG, WEBP, TIFF, HEIC/HEIF"
"""The accepted formats as the error messages and the form fields' descriptions name them."""


@dataclass
class ImageInfo:
    """What the service needs from a validated photo."""

    format: str
    extension: str
    width: int
    height: int
    gps_lat: float | None = None
    gps_lon: float | None = None
    gps_accuracy_m: float | None = None
    """The horizontal accuracy (m) the device states for its GPS fix, None when it states none."""
    focal_length_35mm: float | None = None
    heading_deg: float | None = None
    """The compass heading (deg clockwise from true north), None without a compass."""
    heading_accuracy_deg: float | None = None
    """The compass's accuracy (deg): as stated (widened when magnetic) or the default (:func:`compass_accuracy_deg`)."""
    capture_time: str | None = None
    """When it was taken (ISO 8601: aware, or naive camera time), None when the photo does not say."""
    sequence_id: str | None = None
    """Mapillary's sequence id (one walk), None without one."""
    device: str | None = None
    """The camera (EXIF make and model), None when the photo names neither."""


def validate_image(path: Path, *, max_pixels: int, min_side: int) -> ImageInfo:
    """Open, size-check and fully decode the image; raise :class:`ApiError` with the reason.

    Not an image (or an unsupported format) -> 415; more than ``max_pixels`` (checked from the
    header, before decoding) -> 413; smaller than ``min_side``, a panorama (:func:`refuse_panorama`) or
    truncated/corrupt -> 422. Reference, query and track uploads all pass through here.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            image = Image.open(path)
        except UnidentifiedImageError as exc:
            raise ApiError(415, "not_an_image", "the uploaded file is not an image Pillow can read") from exc
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            raise ApiError(413, "too_many_pixels", f"image rejected as a decompression bomb: {exc}") from exc
        except OSError as exc:
            raise ApiError(422, "corrupt_image", f"the image cannot be read: {exc}") from exc
    with image:
        if image.format not in ACCEPTED_FORMATS:
            raise ApiError(
                415,
                "unsupported_image_format",
                f"image format {image.format} is not accepted (accepted: {ACCEPTED_NAMES})",
            )
        width, height = image.size
        if width * height > max_pixels:
            raise ApiError(
                413,
                "too_many_pixels",
                f"image has {width}x{height} = {width * height} pixels, more than the limit of {max_pixels}",
                {"width": width, "height": height, "limit_pixels": max_pixels},
            )
        if min(width, height) < min_side:
            raise ApiError(
                422, "image_too_small", f"image is {width}x{height}; both sides must be at least {min_side} pixels"
            )
        info = ImageInfo(image.format, ACCEPTED_FORMATS[image.format], width, height)
        exif = _read_exif_into(path, info)
        refuse_panorama(path, width, height, exif)
        try:
            image.load()
        except (OSError, SyntaxError, ValueError) as exc:
            raise ApiError(422, "corrupt_image", f"the image data is truncated or corrupt: {exc}") from exc
    return info


def refuse_panorama(path: Path, width: int, height: int, exif: ExifInfo) -> None:
    """422 ``unsupported_projection`` for a panorama (:func:`geoloc.photos.projection.photo_projection`).

    The method models one perspective camera; the message names the projection, what told it and what
    is supported, and (like every error) no server path.
    """
    has_focal = exif.focal_35mm is not None or exif.focal_mm is not None
    projection = photo_projection(read_head(path), width, height, has_focal_length=has_focal)
    if projection is None:
        return
    raise ApiError(
        422,
        "unsupported_projection",
        f"the photo is a {projection.name} panorama ({projection.evidence}); the service supports ordinary "
        "perspective photos only (one camera, one view, as a phone or a camera takes them) until the method "
        "supports panoramas: upload perspective views cut from it instead",
        {"projection": projection.name, "source": projection.source, "supported": ["perspective"]},
    )


def _read_exif_into(path: Path, info: ImageInfo) -> ExifInfo:
    """Fill GPS position, 35 mm focal length, the compass (heading, accuracy) and the capture from EXIF."""
    block = load_exif(path)  # read and parsed once for both readings
    exif = exif_info(block)
    info.gps_lat, info.gps_lon = (exif.lat, exif.lon) if exif.has_gps else (None, None)
    info.focal_length_35mm = exif.focal_35mm
    info.device = photo_device(exif.make, exif.model)
    capture = capture_of(block)
    info.capture_time = capture.time.isoformat() if capture.time is not None else None
    info.sequence_id = capture.sequence_id
    info.gps_accuracy_m = capture.gps_accuracy_m if info.gps_lat is not None else None
    compass = capture.compass
    if compass is not None:
        info.heading_deg = compass.heading_deg
        info.heading_accuracy_deg = compass_accuracy_deg(compass)
    return exif


def distance_outside_bbox_m(lat: float, lon: float, bbox: tuple[float, float, float, float]) -> float:
    """Metres from a point to a WGS84 bounding box (0 inside); equirectangular, fine at city scale."""
    min_lat, min_lon, max_lat, max_lon = bbox
    d_lat = max(min_lat - lat, 0.0, lat - max_lat)
    d_lon = max(min_lon - lon, 0.0, lon - max_lon)
    metres_per_deg_lat = 111_132.0
    metres_per_deg_lon = 111_320.0 * math.cos(math.radians(min(max(lat, min_lat), max_lat)))
    return math.hypot(d_lat * metres_per_deg_lat, d_lon * metres_per_deg_lon)


STORED_MEDIA_TYPES = {
    ".jpg": "image/jpeg",
    ".png": "image/png",
    ".webp": "image/webp",
    ".tif": "image/tiff",
    ".heic": "image/heic",
}
"""Media type of a stored photo by the extension :data:`ACCEPTED_FORMATS` gave its file."""


def stored_photo_response(path: Path) -> FileResponse:
    """A stored photo as it was uploaded (EXIF included), or 404 when its file is gone."""
    if not path.is_file():
        raise ApiError(404, "not_found", "the stored photo file is missing")
    media_type = STORED_MEDIA_TYPES.get(path.suffix.lower(), "application/octet-stream")
    return FileResponse(path, media_type=media_type, headers={"Cache-Control": "private, max-age=3600"})
