"""EXIF of photos: reading what a phone writes (GPS, focal length, heading) and writing it into JPEGs.

Importing this module registers HEIC/HEIF (iPhones' default format) with Pillow (``pillow-heif``), so every
reader of photos (this module, :mod:`geoloc.photos.photo`, the API's upload check) opens a HEIC as it opens a
JPEG, and reads its EXIF (GPS, heading, focal length) from the same block.

:func:`read_exif` never raises on bad metadata: malformed or missing EXIF gives ``None`` fields
(and whatever could be read). :func:`write_jpeg` writes an RGB array as a JPEG carrying GPS
(optional), focal length, make/model and time, as a phone would.
"""

from __future__ import annotations

import io
import math
from dataclasses import asdict, dataclass
from datetime import datetime
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import piexif
import pillow_heif
from PIL import Image

pillow_heif.register_heif_opener()


@dataclass
class ExifInfo:
    """What a photo's EXIF says (None where absent or unreadable).

    lat, lon: WGS84 degrees (south/west negative). altitude: metres (below sea level negative).
    focal_35mm: FocalLengthIn35mmFilm (mm). focal_mm: FocalLength (mm). heading_deg: GPSImgDirection
    (degrees clockwise from north; ``heading_ref`` says "T" true or "M" magnetic). width, height: pixel
    size of the stored image (before applying ``orientation``, the EXIF Orientation code 1..8).
    """

    lat: float | None = None
    lon: float | None = None
    altitude: float | None = None
    focal_35mm: float | None = None
    focal_mm: float | None = None
    heading_deg: float | None = None
    heading_ref: str | None = None
    make: str | None = None
    model: str | None = None
    width: int | None = None
    height: int | None = None
    orientation: int | None = None
    datetime: str | None = None

    @property
    def has_gps(self) -> bool:
        """Whether both latitude and longitude were read."""
        return self.lat is not None and self.lon is not None

    def as_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict."""
        return asdict(self)


def rational(value: Any) -> float | None:
    """An EXIF rational ((num, den) or int) as a float, None when malformed or den == 0."""
    try:
        if isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, int) for v in value):
            num, den = value
            return None if den == 0 else num / den
        if isinstance(value, int | float):
            return float(value)
    except (TypeError, ValueError):
        pass
    return None


def _dms(value: Any, ref: Any, negative: bytes) -> float | None:
    """GPS (deg, min, sec) rationals + reference letter -> signed degrees."""
    try:
        parts = [rational(v) for v in value]
    except TypeError:
        return None
    if len(parts) != 3:
        return None
    degrees, minutes, seconds = parts
    if degrees is None or minutes is None or seconds is None:
        return None
    deg = degrees + minutes / 60.0 + seconds / 3600.0
    if isinstance(ref, str):
        ref = ref.encode()
    if isinstance(ref, bytes) and ref.strip(b"\x00 ").upper() == negative:
        deg = -deg
    return deg if math.isfinite(deg) else None


def _text(value: Any) -> str | None:
    if isinstance(value, bytes):
        value = value.split(b"\x00", 1)[0].decode("utf-8", "replace")
    if isinstance(value, str):
        value = value.strip()
        return value or None
    return None


@dataclass(frozen=True)
class ExifBlock:
    """A photo's EXIF parsed once: its pixel size (None when Pillow cannot open it) and ``piexif.load``'s dict.

    ``tags`` is None without EXIF or when it is malformed. :func:`exif_info` and
    :func:`geoloc.photos.capture.capture_of` read their fields from it.
    """

    size: tuple[int, int] | None
    tags: dict[str, Any] | None


def load_exif(data: bytes | str | Path) -> ExifBlock:
    """The EXIF of a photo given as bytes or a path, parsed; never raises on bad metadata.

    A path that does not exist raises ``FileNotFoundError`` (that is not a metadata problem).
    """
    raw = Path(data).read_bytes() if isinstance(data, str | Path) else bytes(data)
    size = None
    try:
        with Image.open(io.BytesIO(raw)) as img:
            size = img.size
            block = img.info.get("exif")
    except Exception:  # not an image we can open (e.g. truncated): try the raw bytes
        block = raw if raw[:2] == b"\xff\xd8" else None
    if not block:
        return ExifBlock(size, None)
    try:
        return ExifBlock(size, piexif.load(block))
    except Exception:  # malformed EXIF
        return ExifBlock(size, None)


def read_exif(data: bytes | str | Path) -> ExifInfo:
    """EXIF of a photo given as bytes or a path. Never raises on bad metadata (see module docstring).

    A path that does not exist raises ``FileNotFoundError`` (that is not a metadata problem).
    """
    return exif_info(load_exif(data))


def exif_info(block: ExifBlock) -> ExifInfo:
    """The :class:`ExifInfo` fields of a parsed EXIF block."""
    info = ExifInfo()
    if block.size is not None:
        info.width, info.height = block.size
    exif = block.tags
    if exif is None:
        return info
    zeroth, ex, gps = exif.get("0th") or {}, exif.get("Exif") or {}, exif.get("GPS") or {}

    def safe(fn: Any, *args: Any) -> Any:
        try:
            return fn(*args)
        except Exception:
            return None

    info.make = safe(_text, zeroth.get(piexif.ImageIFD.Make))
    info.model = safe(_text, zeroth.get(piexif.ImageIFD.Model))
    orientation = zeroth.get(piexif.ImageIFD.Orientation)
    info.orientation = orientation if isinstance(orientation, int) and 1 <= orientation <= 8 else None
    info.datetime = safe(_text, ex.get(piexif.ExifIFD.DateTimeOriginal) or zeroth.get(piexif.ImageIFD.DateTime))
    f35 = ex.get(piexif.ExifIFD.FocalLengthIn35mmFilm)
    info.focal_35mm = float(f35) if isinstance(f35, int) and f35 > 0 else None
    fmm = safe(rational, ex.get(piexif.ExifIFD.FocalLength))
    info.focal_mm = fmm if fmm and fmm > 0 else None
    if piexif.GPSIFD.GPSLatitude in gps and piexif.GPSIFD.GPSLongitude in gps:
        lat = safe(_dms, gps[piexif.GPSIFD.GPSLatitude], gps.get(piexif.GPSIFD.GPSLatitudeRef), b"S")
        lon = safe(_dms, gps[piexif.GPSIFD.GPSLongitude], gps.get(piexif.GPSIFD.GPSLongitudeRef), b"W")
        if lat is not None and lon is not None and -90 <= lat <= 90 and -180 <= lon <= 180 and (lat, lon) != (0, 0):
            info.lat, info.lon = lat, lon
    alt = safe(rational, gps.get(piexif.GPSIFD.GPSAltitude))
    if alt is not None and math.isfinite(alt):
        info.altitude = -alt if gps.get(piexif.GPSIFD.GPSAltitudeRef) == 1 else alt
    heading = safe(rational, gps.get(piexif.GPSIFD.GPSImgDirection))
    if heading is not None and math.isfinite(heading):
        info.heading_deg = heading % 360.0
        info.heading_ref = safe(_text, gps.get(piexif.GPSIFD.GPSImgDirectionRef))
    return info


def _to_rational(value: float, denominator: int = 10000) -> tuple[int, int]:
    frac = Fraction(value).limit_denominator(denominator)
    return frac.numerator, frac.denominator


def _to_dms(deg: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    """Unsigned degrees -> ((d, 1), (m, 1), (s * 10^6, 10^6)), about 0.03 mm precision."""
    deg = abs(deg)
    d = int(deg)
    m = int((deg - d) * 60.0)
    s = (deg - d - m / 60.0) * 3600.0
    micro = int(round(s * 1_000_000))
    if micro >= 60_000_000:  # rounding spill-over
        micro -= 60_000_000
        m += 1
    if m >= 60:
        m -= 60
        d += 1
    return (d, 1), (m, 1), (micro, 1_000_000)


@dataclass(frozen=True)
class ExifFields:
    """What :func:`write_jpeg` and :func:`exif_bytes` write into a photo's EXIF.

    lat, lon: WGS84 degrees, or None for a photo without GPS; altitude: m. focal_35mm: 35 mm-equivalent focal
    length (EXIF stores it as an integer number of mm); focal_mm: the physical focal length. heading_deg:
    written as GPSImgDirection (true north) when given; phones often do not. make, model: the camera.
    taken: DateTimeOriginal (local time, whole seconds). The optional fields below are written only when
    given, so that a block without them is byte-for-byte what it was before they existed: ``subsec_time``
    (digits, e.g. ``"250"``: SubSecTimeOriginal and SubSecTime), ``description`` (ImageDescription, e.g. a
    Mapillary-style JSON carrying the compass's stated accuracy, for which EXIF has no tag),
    ``gps_accuracy_m`` (GPSHPositioningError, metres).
    """

    lat: float | None = None
    lon: float | None = None
    focal_35mm: float | None = None
    focal_mm: float | None = None
    altitude: float | None = None
    heading_deg: float | None = None
    make: str = "GeolocSim"
    model: str = "StreetCam 1"
    taken: datetime | None = None
    subsec_time: str | None = None
    description: str | None = None
    gps_accuracy_m: float | None = None


def exif_bytes(width: int, height: int, fields: ExifFields) -> bytes:
    """The EXIF block (APP1 payload) of an image ``width`` x ``height`` with ``fields`` (:class:`ExifFields`)."""
    lat, lon, altitude, gps_accuracy_m = fields.lat, fields.lon, fields.altitude, fields.gps_accuracy_m
    focal_35mm, focal_mm, heading_deg = fields.focal_35mm, fields.focal_mm, fields.heading_deg
    make, model, taken = fields.make, fields.model, fields.taken
    subsec_time, description = fields.subsec_time, fields.description
    stamp = (taken or datetime(2024, 6, 1, 12, 0, 0)).strftime("%Y:%m:%d %H:%M:%S").encode()
    zeroth = {
        piexif.ImageIFD.Make: make.encode(),
        piexif.ImageIFD.Model: model.encode(),
        piexif.ImageIFD.Orientation: 1,
        piexif.ImageIFD.DateTime: stamp,
        piexif.ImageIFD.Software: b"geoloc.sim",
    }
    if description is not None:
        zeroth[piexif.ImageIFD.ImageDescription] = description.encode()
    exif: dict[int, Any] = {
        piexif.ExifIFD.DateTimeOriginal: stamp,
        piexif.ExifIFD.PixelXDimension: int(width),
        piexif.ExifIFD.PixelYDimension: int(height),
    }
    if subsec_time is not None:
        exif[piexif.ExifIFD.SubSecTimeOriginal] = subsec_time.encode()
        exif[piexif.ExifIFD.SubSecTime] = subsec_time.encode()
    if focal_35mm is not None:
        exif[piexif.ExifIFD.FocalLengthIn35mmFilm] = int(round(focal_35mm))
    if focal_mm is not None:
        exif[piexif.ExifIFD.FocalLength] = _to_rational(focal_mm, 1000)
    gps: dict[int, Any] = {}
    if lat is not None and lon is not None:
        gps[piexif.GPSIFD.GPSVersionID] = (2, 3, 0, 0)
        gps[piexif.GPSIFD.GPSLatitudeRef] = b"N" if lat >= 0 else b"S"
        gps[piexif.GPSIFD.GPSLatitude] = _to_dms(lat)
        gps[piexif.GPSIFD.GPSLongitudeRef] = b"E" if lon >= 0 else b"W"
        gps[piexif.GPSIFD.GPSLongitude] = _to_dms(lon)
        if altitude is not None:
            gps[piexif.GPSIFD.GPSAltitudeRef] = 0 if altitude >= 0 else 1
            gps[piexif.GPSIFD.GPSAltitude] = _to_rational(abs(altitude), 100)
        if gps_accuracy_m is not None:
            gps[piexif.GPSIFD.GPSHPositioningError] = _to_rational(abs(float(gps_accuracy_m)), 100)
    if heading_deg is not None:
        gps[piexif.GPSIFD.GPSImgDirectionRef] = b"T"
        gps[piexif.GPSIFD.GPSImgDirection] = _to_rational(float(heading_deg) % 360.0, 100)
    block: bytes = piexif.dump({"0th": zeroth, "Exif": exif, "GPS": gps, "1st": {}, "thumbnail": None})
    return block


def write_jpeg(path: str | Path, rgb: np.ndarray, fields: ExifFields, quality: int = 90) -> Path:
    """Write (H, W, 3) uint8 RGB as a JPEG with EXIF ``fields`` (:class:`ExifFields`); returns the path."""
    path = Path(path)
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w = rgb.shape[:2]
    block = exif_bytes(w, h, fields)
    Image.fromarray(rgb, "RGB").save(path, "JPEG", quality=int(quality), exif=block)
    return path
