"""Geotagging as people do it: a GPS logger's track (GPX) and the description file ``mapillary_tools`` writes.

**The track.** :func:`read_gpx` reads every timed track point of a GPX file (all tracks and segments, with
``gpxpy``) into one :class:`Track` sorted by time; a GPX time without a zone is UTC, as the format says.
:meth:`Track.locate` places a capture time on it:

- the position is interpolated linearly in latitude and longitude between the two points around the time
  (points a logger writes every few seconds are metres apart, where the straight line is the geodesic);
- the heading is the direction of travel: the bearing from the last point before the time to the first
  after it, widened point by point (within :data:`TRAVEL_WINDOW_S` of the time) until they lie
  :data:`MIN_TRAVEL_M` apart; None when the walker stood still;
- a time before the track's first point or after its last, or inside a gap longer than ``max_gap_s``
  (:data:`MAX_GAP_S`: the logger was off), is :class:`Unplaced` with the reason in words.

**Capture times.** :func:`track_time` puts a photo's capture time on the track's clock: an aware time is
converted to UTC, a naive one (a camera's wall clock, EXIF without ``OffsetTimeOriginal``) is taken as UTC,
and the offset in seconds is added (a camera clock that is off, or set to local time: ``-7200`` for UTC+2).

**Mapillary's description file.** :func:`read_mapillary_descriptions` reads
``mapillary_image_description.json`` (a JSON list; one object per image: ``filename``, ``MAPLatitude``,
``MAPLongitude``, ``MAPCaptureTime``, ``MAPCompassHeading``, ``MAPSequenceUUID``, ...; entries with an
``error`` are images mapillary_tools could not process and are left out). Its fields are read with the
rules of :mod:`geoloc.photos.capture` (the same time format, the same compass preference: ``TrueHeading``,
else ``MagneticHeading`` widened by the declination bound).

Decision (where this lives): in ``geoloc/photos``, beside :mod:`geoloc.photos.capture` whose parsers it
reuses, rather than under ``cli/``: it is what a photo's capture says once a track or a description file is
added to its EXIF, it is pure (files and datetimes in, positions out; no HTTP) and it is typed under
``mypy --strict`` with the runtime. Today only the command line imports it (``geoloc ingest --gpx``,
:mod:`cli.ingest_geotag`, which turns its answers into the reference upload's form fields); the service and
the workers do not.
"""

from __future__ import annotations

import bisect
import json
import math
from collections import defaultdict
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path, PurePosixPath
from typing import Any

import gpxpy
import gpxpy.gpx

from geoloc.photos.capture import CompassReading, mapillary_compass, parse_mapillary_time

MAX_GAP_S = 1800.0
"""Longest time (s) between two track points that a photo is interpolated across (exiftool's default too)."""
MIN_TRAVEL_M = 2.0
"""Shortest travel (m) that gives a direction of travel: below it the walker stood still (GPS noise)."""
TRAVEL_WINDOW_S = 30.0
"""The track points that may give a photo's direction of travel lie within this many seconds of it."""
DESCRIPTION_FILE = "mapillary_image_description.json"
"""The name mapillary_tools gives its description file, in the folder of the images."""
_METRES_PER_DEG_LAT = 111_132.0
_METRES_PER_DEG_LON_EQUATOR = 111_320.0


class GeotagError(ValueError):
    """A GPX track or a description file that cannot be read (the message says why, without paths)."""


@dataclass(frozen=True)
class TrackPoint:
    """One timed point of a track: time (aware, UTC), WGS84 degrees."""

    time: datetime
    lat: float
    lon: float


@dataclass(frozen=True)
class TrackFix:
    """Where the track puts a time.

    lat, lon: WGS84 degrees. heading_deg: the direction of travel (deg from true north), None when standing
    still. gap_s: the time between the two track points it lies between (s; 0 on a point).
    """

    time: datetime
    lat: float
    lon: float
    heading_deg: float | None
    gap_s: float


@dataclass(frozen=True)
class Unplaced:
    """A time the track cannot place, and why (in words, for the ingest summary)."""

    time: datetime
    reason: str


def _stamp(when: datetime) -> str:
    """A UTC time as ``2014-06-07T10:24:05.656Z`` (milliseconds only when there are some)."""
    text = when.astimezone(UTC).replace(tzinfo=None).isoformat(timespec="milliseconds")
    return (text[:-4] if text.endswith(".000") else text) + "Z"


def _span(seconds: float) -> str:
    """A duration in words: ``42 s``, ``3 min 5 s``, ``2 h 10 min``."""
    seconds = abs(seconds)
    if seconds < 60:
        return f"{seconds:.1f} s" if seconds < 10 else f"{seconds:.0f} s"
    minutes, secs = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes} min"


def _metres(a: TrackPoint, b: TrackPoint) -> tuple[float, float]:
    """(east, north) metres from ``a`` to ``b`` (equirectangular: exact enough over a walk's steps)."""
    mid = math.radians((a.lat + b.lat) / 2.0)
    return (b.lon - a.lon) * _METRES_PER_DEG_LON_EQUATOR * math.cos(mid), (b.lat - a.lat) * _METRES_PER_DEG_LAT


@dataclass(frozen=True)
class Track:
    """A GPS track: its timed points in time order (at least one)."""

    points: tuple[TrackPoint, ...]

    @property
    def start(self) -> datetime:
        """The first point's time."""
        return self.points[0].time

    @property
    def end(self) -> datetime:
        """The last point's time."""
        return self.points[-1].time

    def locate(self, when: datetime, *, max_gap_s: float = MAX_GAP_S) -> TrackFix | Unplaced:
        """Where the track was at ``when`` (aware; see :func:`track_time`), or why it cannot say."""
        when = when.astimezone(UTC)
        if when < self.start:
            return Unplaced(
                when,
                f"taken at {_stamp(when)}, {_span((self.start - when).total_seconds())} before the GPX track "
                f"starts ({_stamp(self.start)}; the track spans {_stamp(self.start)} to {_stamp(self.end)})",
            )
        if when > self.end:
            return Unplaced(
                when,
                f"taken at {_stamp(when)}, {_span((when - self.end).total_seconds())} after the GPX track "
                f"ends ({_stamp(self.end)}; the track spans {_stamp(self.start)} to {_stamp(self.end)})",
            )
        times = [p.time for p in self.points]
        after = bisect.bisect_right(times, when)  # first point later than ``when``
        before = after - 1  # last point at or before it
        a = self.points[before]
        if a.time == when:
            return TrackFix(when, a.lat, a.lon, self._travel(when, times), 0.0)
        b = self.points[after]
        gap = (b.time - a.time).total_seconds()
        if gap > max_gap_s:
            return Unplaced(
                when,
                f"taken at {_stamp(when)}, in a gap of {_span(gap)} between the GPX track's points "
                f"{_stamp(a.time)} and {_stamp(b.time)} (more than {_span(max_gap_s)}: the logger was off)",
            )
        share = (when - a.time).total_seconds() / gap
        lat = a.lat + share * (b.lat - a.lat)
        lon = a.lon + share * (b.lon - a.lon)
        return TrackFix(when, lat, lon, self._travel(when, times), gap)

    def _travel(self, when: datetime, times: list[datetime]) -> float | None:
        """The direction of travel at ``when`` (deg from true north), None when standing still (module doc)."""
        window = timedelta(seconds=TRAVEL_WINDOW_S)
        first = bisect.bisect_left(times, when) - 1  # last point strictly before
        last = bisect.bisect_right(times, when)  # first point strictly after
        first, last = max(first, 0), min(last, len(times) - 1)
        while True:
            east, north = _metres(self.points[first], self.points[last])
            if math.hypot(east, north) >= MIN_TRAVEL_M:
                return math.degrees(math.atan2(east, north)) % 360.0
            grew = False
            if first > 0 and when - times[first - 1] <= window:
                first, grew = first - 1, True
            if last < len(times) - 1 and times[last + 1] - when <= window:
                last, grew = last + 1, True
            if not grew:
                return None


def track_time(capture: datetime, offset_s: float = 0.0) -> datetime:
    """A photo's capture time on the track's clock (UTC): naive taken as UTC, then ``offset_s`` added."""
    aware = capture.replace(tzinfo=UTC) if capture.tzinfo is None else capture.astimezone(UTC)
    return aware + timedelta(seconds=offset_s)


def _utc(when: datetime) -> datetime:
    return when.replace(tzinfo=UTC) if when.tzinfo is None else when.astimezone(UTC)


def read_gpx(source: bytes | str | Path) -> Track:
    """Every timed track point of a GPX file (bytes, or a path), in time order; :class:`GeotagError` if none."""
    data = Path(source).read_bytes() if isinstance(source, str | Path) else source
    try:
        parsed = gpxpy.parse(data.decode("utf-8-sig", "replace"))
    except gpxpy.gpx.GPXException as exc:
        raise GeotagError(f"not a GPX file: {exc}") from exc
    points = [
        TrackPoint(_utc(point.time), float(point.latitude), float(point.longitude))
        for track in parsed.tracks
        for segment in track.segments
        for point in segment.points
        if point.time is not None
        and math.isfinite(point.latitude)
        and math.isfinite(point.longitude)
        and -90.0 <= point.latitude <= 90.0
        and -180.0 <= point.longitude <= 180.0
    ]
    if not points:
        raise GeotagError("the GPX file has no track points with a time (<trk><trkseg><trkpt><time>)")
    points.sort(key=lambda p: p.time)  # stable: points of one time keep the file's order
    return Track(tuple(points))


@dataclass(frozen=True)
class MapillaryImage:
    """What mapillary_tools' description file says of one image (None where it does not say)."""

    filename: str
    lat: float | None = None
    lon: float | None = None
    time: datetime | None = None
    compass: CompassReading | None = None
    sequence_id: str | None = None


def _coordinate(value: Any, limit: float) -> float | None:
    """A finite number (JSON number or numeric string) within [-limit, limit], else None."""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        return None
    try:
        out = float(value)
    except ValueError:
        return None
    return out if math.isfinite(out) and -limit <= out <= limit else None


def mapillary_image(entry: dict[str, Any]) -> MapillaryImage | None:
    """One object of the description file, None when it has no ``filename`` or is an error entry."""
    filename = entry.get("filename")
    if not isinstance(filename, str) or not filename.strip() or "error" in entry:
        return None
    lat, lon = _coordinate(entry.get("MAPLatitude"), 90.0), _coordinate(entry.get("MAPLongitude"), 180.0)
    if lat is None or lon is None or (lat, lon) == (0.0, 0.0):
        lat = lon = None
    true, magnetic = mapillary_compass(entry, None)
    sequence = entry.get("MAPSequenceUUID")
    return MapillaryImage(
        filename=filename.strip(),
        lat=lat,
        lon=lon,
        time=parse_mapillary_time(entry.get("MAPCaptureTime")),
        compass=true or magnetic,
        sequence_id=sequence.strip() or None if isinstance(sequence, str) else None,
    )


@dataclass(frozen=True)
class MapillaryDescriptions:
    """The images of description files, found by a photo's path relative to the ingested folder."""

    by_path: dict[str, MapillaryImage]
    by_name: dict[str, list[MapillaryImage]]

    def for_photo(self, relative: str) -> MapillaryImage | None:
        """The entry of the photo at ``relative`` (posix, under the folder); else of its file name, if unique."""
        found = self.by_path.get(relative)
        if found is not None:
            return found
        named = self.by_name.get(PurePosixPath(relative).name, [])
        return named[0] if len(named) == 1 else None

    def __len__(self) -> int:
        """How many images the files describe."""
        return len(self.by_path)


NO_DESCRIPTIONS = MapillaryDescriptions({}, {})


def _relative_name(filename: str, folder: Path, root: Path) -> str:
    """A description's ``filename`` (absolute, or relative to its file's folder) relative to ``root``."""
    path = Path(filename)
    path = path if path.is_absolute() else folder / path
    try:
        return path.resolve().relative_to(root.resolve()).as_posix()
    except ValueError:  # elsewhere (the images were moved since): matched by file name only
        return PurePosixPath(filename.replace("\\", "/")).name


def read_mapillary_descriptions(files: list[Path], root: Path) -> MapillaryDescriptions:
    """The images of description files (each in the folder of its images) under ``root``; :class:`GeotagError`."""
    by_path: dict[str, MapillaryImage] = {}
    by_name: dict[str, list[MapillaryImage]] = defaultdict(list)
    for file in files:
        shown = file.relative_to(root).as_posix() if file.is_relative_to(root) else file.name
        try:
            entries = json.loads(file.read_bytes())
        except (OSError, ValueError) as exc:
            raise GeotagError(f"{shown} is not a Mapillary image description (JSON): {exc}") from exc
        if not isinstance(entries, list):
            raise GeotagError(f"{shown} is not a Mapillary image description: not a JSON list of images")
        for entry in entries:
            image = mapillary_image(entry) if isinstance(entry, dict) else None
            if image is None:
                continue
            relative = _relative_name(image.filename, file.parent, root)
            by_path.setdefault(relative, image)
            by_name[PurePosixPath(relative).name].append(image)
    return MapillaryDescriptions(by_path, dict(by_name))
