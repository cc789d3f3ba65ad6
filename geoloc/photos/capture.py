"""What a photo says about its capture: when, in which walk, and where the camera pointed (the compass).

:func:`read_capture` (or :func:`capture_of`, on the block :func:`geoloc.photos.exif.load_exif` parsed once for
:func:`geoloc.photos.exif.exif_info` too) reads:

- EXIF ``DateTimeOriginal`` + ``SubSecTimeOriginal`` (+ ``OffsetTimeOriginal`` when present);
- EXIF ``GPSImgDirection`` + ``GPSImgDirectionRef`` ("T" true, "M" magnetic);
- Mapillary's JSON in the 0th-IFD ``ImageDescription``: ``MAPCompassHeading`` (``TrueHeading``,
  ``MagneticHeading``, ``AccuracyDegrees``), ``MAPCaptureTime`` (``"2014_06_07_10_24_05_656"``, UTC),
  ``MAPSequenceUUID``, ``MAPPhotoUUID`` and ``MAPGPSAccuracyMeters``;
- the GPS fix's stated accuracy: EXIF ``GPSHPositioningError`` (metres), else Mapillary's
  ``MAPGPSAccuracyMeters`` (a phone's horizontal accuracy: iOS and Android state the radius of about 68 %
  confidence); a value that is not a finite number in (0, :data:`MAX_GPS_ACCURACY_M`] is left out.

Like ``read_exif`` it never raises on bad metadata: a description that is not JSON, a heading that is not a
finite number in [0, 360], an accuracy that is not a finite number in (0, 180] are left out (``None``).

**Which compass.** Mapillary's ``TrueHeading`` first (it comes with an accuracy), then EXIF with ref "T",
then Mapillary's ``MagneticHeading``, then EXIF with ref "M" (or with no or an unknown ref: the wider
reading is the conservative guess). iOS writes a negative heading or accuracy for "invalid"; both are
dropped (a negative accuracy drops its heading too).

**Magnetic to true.** No declination model ships with the project (a WMM package would be a new
dependency), so a magnetic heading is kept as it is (declination taken as 0) and its accuracy is widened
by :data:`DECLINATION_BOUND_DEG` in quadrature: ``accuracy = hypot(stated or 0, 25)``; the reading's
``reference`` is ``"magnetic-converted"``. 25 degrees bounds the declination where people live
(Europe under 15, the contiguous US under 17, New Zealand up to about 25); near the magnetic poles it can
be larger and the prior's outlier floor (:mod:`geoloc.photos.heading_prior`) carries it. A caller that has a
declination (from a model) passes ``declination_deg``: it is added and the accuracy is not widened.

**Capture time.** ``time`` is timezone-aware where the photo says its zone: EXIF with
``OffsetTimeOriginal``, else Mapillary's ``MAPCaptureTime`` (UTC), else EXIF without offset as a *naive*
datetime: the camera's wall-clock time, comparable only with other naive times of the same camera.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Literal

import piexif

from geoloc.photos.exif import ExifBlock, load_exif, rational

CompassSource = Literal["exif", "mapillary"]
CompassReference = Literal["true", "magnetic-converted"]
TimeSource = Literal["exif", "mapillary"]

MAX_GPS_ACCURACY_M = 10_000.0
"""A stated GPS error above this (m) is not a fix's accuracy: it is left out."""

DECLINATION_BOUND_DEG = 25.0
"""Bound (deg) on the magnetic declination where people take photos; widens a magnetic heading's accuracy."""


@dataclass(frozen=True)
class CompassReading:
    """Where the camera pointed, as the photo's metadata says.

    heading_deg: degrees clockwise from true north, in [0, 360). accuracy_deg: the stated accuracy (deg,
    > 0; for a magnetic heading widened by the declination bound), None where none is stated.
    source: "exif" (GPSImgDirection) or "mapillary" (the JSON's MAPCompassHeading).
    reference: "true", or "magnetic-converted" (a magnetic heading, see the module docstring).
    """

    heading_deg: float
    accuracy_deg: float | None
    source: CompassSource
    reference: CompassReference


@dataclass(frozen=True)
class CaptureInfo:
    """When and in which walk a photo was taken, and its compass (None where the photo does not say).

    time: the capture time (aware, or naive local camera time; rule in the module docstring).
    time_source: which field gave ``time``. sequence_id: Mapillary's ``MAPSequenceUUID`` (one walk).
    photo_id: Mapillary's ``MAPPhotoUUID``. compass: the preferred :class:`CompassReading`.
    gps_accuracy_m: the horizontal accuracy the device states for its GPS fix (m; rule in the module docstring).
    """

    time: datetime | None = None
    time_source: TimeSource | None = None
    sequence_id: str | None = None
    photo_id: str | None = None
    compass: CompassReading | None = None
    gps_accuracy_m: float | None = None


def _number(value: Any) -> float | None:
    """A finite float from a JSON number or numeric string, else None (bools are not numbers)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        out = float(value)
    elif isinstance(value, str):
        try:
            out = float(value.strip())
        except ValueError:
            return None
    else:
        return None
    return out if math.isfinite(out) else None


def _heading(value: Any) -> float | None:
    """A heading in [0, 360] (360 read as 0), else None."""
    deg = _number(value)
    return None if deg is None or not 0.0 <= deg <= 360.0 else deg % 360.0


def _accuracy(value: Any) -> float | None:
    """An accuracy in (0, 180] degrees, else None."""
    deg = _number(value)
    return deg if deg is not None and 0.0 < deg <= 180.0 else None


def magnetic_to_true(
    heading_deg: float, accuracy_deg: float | None, source: CompassSource, declination_deg: float | None = None
) -> CompassReading:
    """A magnetic heading (deg clockwise from magnetic north) as a true-north :class:`CompassReading`.

    With ``declination_deg`` (deg, east positive) it is added; without it the heading is kept and the
    accuracy becomes ``hypot(accuracy_deg or 0, DECLINATION_BOUND_DEG)``.
    """
    if declination_deg is not None and math.isfinite(declination_deg):
        return CompassReading((heading_deg + declination_deg) % 360.0, accuracy_deg, source, "magnetic-converted")
    widened = math.hypot(accuracy_deg or 0.0, DECLINATION_BOUND_DEG)
    return CompassReading(heading_deg % 360.0, widened, source, "magnetic-converted")


def mapillary_description(description: Any) -> dict[str, Any] | None:
    """The Mapillary JSON object of an ``ImageDescription`` (bytes or str), None when it is not one."""
    if isinstance(description, bytes):
        description = description.split(b"\x00", 1)[0].decode("utf-8", "replace")
    if not isinstance(description, str) or not description.lstrip().startswith("{"):
        return None
    try:
        parsed = json.loads(description)
    except ValueError:
        return None
    return parsed if isinstance(parsed, dict) else None


_MAP_TIME = re.compile(r"^(\d{4})_(\d{2})_(\d{2})_(\d{2})_(\d{2})_(\d{2})(?:_(\d{1,6}))?$")


def parse_mapillary_time(value: Any) -> datetime | None:
    """``MAPCaptureTime`` ("YYYY_MM_DD_hh_mm_ss_fff", UTC) as an aware UTC datetime, None when malformed."""
    match = _MAP_TIME.match(value.strip()) if isinstance(value, str) else None
    if match is None:
        return None
    year, month, day, hour, minute, second, fraction = match.groups()
    try:
        stamp = datetime(int(year), int(month), int(day), int(hour), int(minute), int(second), tzinfo=UTC)
    except ValueError:
        return None
    return stamp.replace(microsecond=int((fraction or "0").ljust(6, "0")))


def _ascii(value: Any) -> str | None:
    if isinstance(value, bytes):
        value = value.split(b"\x00", 1)[0].decode("ascii", "replace")
    return value.strip() or None if isinstance(value, str) else None


_OFFSET = re.compile(r"^([+-])(\d{2}):(\d{2})$")


def parse_exif_time(original: Any, subsec: Any = None, offset: Any = None) -> datetime | None:
    """EXIF's original time as a datetime: aware with a valid offset, naive without.

    original: ``DateTimeOriginal`` ("YYYY:MM:DD hh:mm:ss"); subsec: ``SubSecTimeOriginal`` (fraction digits);
    offset: ``OffsetTimeOriginal`` ("+hh:mm"). None when the date is malformed; a malformed sub-second or
    offset is left out.
    """
    text = _ascii(original)
    if text is None:
        return None
    try:
        stamp = datetime.strptime(text, "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return None
    digits = _ascii(subsec)
    if digits is not None and digits.isdigit():
        stamp = stamp.replace(microsecond=int(digits[:6].ljust(6, "0")))
    zone = _OFFSET.match(_ascii(offset) or "")
    if zone is not None:
        sign, hours, minutes = zone.groups()
        delta = timedelta(hours=int(hours), minutes=int(minutes))
        if delta <= timedelta(hours=14):
            stamp = stamp.replace(tzinfo=timezone(-delta if sign == "-" else delta))
    return stamp


def mapillary_compass(meta: dict[str, Any], declination_deg: float | None) -> tuple[CompassReading | None, ...]:
    """(true reading, magnetic reading) from ``MAPCompassHeading``, each None when absent or invalid."""
    compass = meta.get("MAPCompassHeading")
    if not isinstance(compass, dict):
        return None, None
    raw_accuracy = _number(compass.get("AccuracyDegrees"))
    if raw_accuracy is not None and raw_accuracy < 0:  # iOS: a negative accuracy means the heading is invalid
        return None, None
    accuracy = _accuracy(raw_accuracy)
    true = _heading(compass.get("TrueHeading"))
    magnetic = _heading(compass.get("MagneticHeading"))
    return (
        None if true is None else CompassReading(true, accuracy, "mapillary", "true"),
        None if magnetic is None else magnetic_to_true(magnetic, accuracy, "mapillary", declination_deg),
    )


def _exif_compass(gps: dict[int, Any], declination_deg: float | None) -> tuple[CompassReading | None, ...]:
    """(true reading, magnetic reading) from ``GPSImgDirection`` and its ref, one of them set at most."""
    heading = _heading(rational(gps.get(piexif.GPSIFD.GPSImgDirection)))
    if heading is None:
        return None, None
    if (_ascii(gps.get(piexif.GPSIFD.GPSImgDirectionRef)) or "").upper() == "T":
        return CompassReading(heading, None, "exif", "true"), None
    return None, magnetic_to_true(heading, None, "exif", declination_deg)


def _gps_accuracy(gps: dict[int, Any], meta: dict[str, Any]) -> float | None:
    """The stated accuracy of the GPS fix (m): EXIF ``GPSHPositioningError``, else ``MAPGPSAccuracyMeters``."""
    exif = rational(gps.get(piexif.GPSIFD.GPSHPositioningError))
    for stated in (exif, _number(meta.get("MAPGPSAccuracyMeters"))):
        if stated is not None and 0.0 < stated <= MAX_GPS_ACCURACY_M:
            return stated
    return None


def capture_from_exif(exif: dict[str, Any], *, declination_deg: float | None = None) -> CaptureInfo:
    """:class:`CaptureInfo` from a ``piexif.load`` dict (see the module docstring for the rules)."""
    zeroth, ex, gps = exif.get("0th") or {}, exif.get("Exif") or {}, exif.get("GPS") or {}
    meta = mapillary_description(zeroth.get(piexif.ImageIFD.ImageDescription)) or {}
    map_true, map_magnetic = mapillary_compass(meta, declination_deg)
    exif_true, exif_magnetic = _exif_compass(gps, declination_deg)
    compass = map_true or exif_true or map_magnetic or exif_magnetic
    exif_time = parse_exif_time(
        ex.get(piexif.ExifIFD.DateTimeOriginal),
        ex.get(piexif.ExifIFD.SubSecTimeOriginal),
        ex.get(piexif.ExifIFD.OffsetTimeOriginal),
    )
    map_time = parse_mapillary_time(meta.get("MAPCaptureTime"))
    time: datetime | None
    source: TimeSource | None
    if exif_time is not None and exif_time.tzinfo is not None:
        time, source = exif_time, "exif"
    elif map_time is not None:
        time, source = map_time, "mapillary"
    else:
        time, source = exif_time, None if exif_time is None else "exif"
    sequence, photo = meta.get("MAPSequenceUUID"), meta.get("MAPPhotoUUID")
    return CaptureInfo(
        time=time,
        time_source=source,
        sequence_id=sequence.strip() or None if isinstance(sequence, str) else None,
        photo_id=photo.strip() or None if isinstance(photo, str) else None,
        compass=compass,
        gps_accuracy_m=_gps_accuracy(gps, meta),
    )


def read_capture(data: bytes | str | Path, *, declination_deg: float | None = None) -> CaptureInfo:
    """:class:`CaptureInfo` of a photo given as bytes or a path; never raises on bad metadata.

    declination_deg: the magnetic declination at the photo (deg, east positive) when the caller knows it;
    it converts a magnetic heading instead of the declination bound. A missing path raises ``FileNotFoundError``.
    """
    return capture_of(load_exif(data), declination_deg=declination_deg)


def capture_of(block: ExifBlock, *, declination_deg: float | None = None) -> CaptureInfo:
    """:class:`CaptureInfo` of an EXIF block parsed by :func:`geoloc.photos.exif.load_exif`; never raises."""
    if block.tags is None:
        return CaptureInfo()
    try:
        return capture_from_exif(block.tags, declination_deg=declination_deg)
    except Exception:  # a field of a type piexif let through
        return CaptureInfo()


def photo_device(make: str | None, model: str | None) -> str | None:
    """One device's name for grouping (EXIF make and model, stripped; None when the photo names neither)."""
    name = " ".join(part.strip() for part in (make, model) if part and part.strip())
    return name or None
