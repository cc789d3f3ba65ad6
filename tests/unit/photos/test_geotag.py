"""A GPX track placing capture times (position, direction of travel, refusals) and Mapillary's description file."""

from __future__ import annotations

import json
import math
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import pytest

from geoloc.photos.geotag import (
    MAX_GAP_S,
    GeotagError,
    TrackFix,
    Unplaced,
    read_gpx,
    read_mapillary_descriptions,
    track_time,
)

T0 = datetime(2024, 6, 1, 10, 0, 0, tzinfo=UTC)
LAT0, LON0 = 55.7, 13.19
METRES_PER_DEG_LAT = 111_132.0


def gpx_text(points: list[tuple[datetime | None, float, float]], *, segments: int = 1) -> str:
    """A GPX 1.1 document of one track; ``points`` (time or None, lat, lon) split over ``segments`` segments."""
    per = math.ceil(len(points) / segments)
    chunks = [points[i : i + per] for i in range(0, len(points), per)]
    body = "".join(
        "<trkseg>"
        + "".join(
            f'<trkpt lat="{lat:.9f}" lon="{lon:.9f}">'
            + (f"<time>{t.astimezone(UTC).strftime('%Y-%m-%dT%H:%M:%S.%fZ')}</time>" if t else "")
            + "</trkpt>"
            for t, lat, lon in chunk
        )
        + "</trkseg>"
        for chunk in chunks
    )
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n<gpx version="1.1" creator="test" '
        f'xmlns="http://www.topografix.com/GPX/1/1"><trk><name>walk</name>{body}</trk></gpx>'
    )


def east_walk(n: int = 10, step_s: float = 2.0, step_m: float = 1.5) -> list[tuple[datetime | None, float, float]]:
    """A walk due east: ``n`` points ``step_s`` seconds and ``step_m`` metres apart."""
    deg_per_m_lon = 1.0 / (111_320.0 * math.cos(math.radians(LAT0)))
    return [(T0 + timedelta(seconds=i * step_s), LAT0, LON0 + i * step_m * deg_per_m_lon) for i in range(n)]


def test_positions_between_points_are_interpolated_and_the_heading_is_the_direction_of_travel() -> None:
    track = read_gpx(gpx_text(east_walk(), segments=2).encode())
    assert len(track.points) == 10 and track.start == T0 and track.end == T0 + timedelta(seconds=18)
    fix = track.locate(T0 + timedelta(seconds=3))  # half-way between the 2nd and 3rd points
    assert isinstance(fix, TrackFix)
    assert fix.lat == pytest.approx(LAT0) and fix.lon == pytest.approx((track.points[1].lon + track.points[2].lon) / 2)
    assert fix.gap_s == pytest.approx(2.0)
    assert fix.heading_deg == pytest.approx(90.0, abs=0.01)
    on_point = track.locate(T0 + timedelta(seconds=4))
    assert isinstance(on_point, TrackFix) and (on_point.lat, on_point.lon, on_point.gap_s) == (
        track.points[2].lat,
        track.points[2].lon,
        0.0,
    )
    assert on_point.heading_deg == pytest.approx(90.0, abs=0.01), "from the points either side"
    walking_north = read_gpx(gpx_text([(T0 + timedelta(seconds=i), LAT0 + i * 2e-5, LON0) for i in range(5)]).encode())
    north = walking_north.locate(T0 + timedelta(seconds=2.5))
    assert isinstance(north, TrackFix) and north.heading_deg == pytest.approx(0.0, abs=0.01)


def test_standing_still_gives_no_heading_and_short_steps_are_widened() -> None:
    still = read_gpx(gpx_text([(T0 + timedelta(seconds=i), LAT0, LON0) for i in range(6)]).encode())
    fix = still.locate(T0 + timedelta(seconds=2.5))
    assert isinstance(fix, TrackFix) and fix.heading_deg is None
    slow = read_gpx(gpx_text(east_walk(n=12, step_s=1.0, step_m=0.4)).encode())  # 0.4 m per point: widened to 2 m
    fix = slow.locate(T0 + timedelta(seconds=5.5))
    assert isinstance(fix, TrackFix) and fix.heading_deg == pytest.approx(90.0, abs=0.01)


def test_times_outside_the_track_or_in_a_gap_are_unplaced_with_the_reason() -> None:
    points = east_walk(n=4)
    points.append((points[-1][0] + timedelta(seconds=MAX_GAP_S + 600), LAT0, LON0 + 0.01))  # the logger was off
    track = read_gpx(gpx_text(points).encode())
    before = track.locate(T0 - timedelta(seconds=90))
    assert isinstance(before, Unplaced)
    assert "1 min 30 s before the GPX track starts (2024-06-01T10:00:00Z" in before.reason
    after = track.locate(track.end + timedelta(seconds=5))
    assert isinstance(after, Unplaced) and "5.0 s after the GPX track ends" in after.reason
    gap = track.locate(T0 + timedelta(seconds=100))
    assert isinstance(gap, Unplaced) and "in a gap of 40 min 0 s" in gap.reason and "logger was off" in gap.reason
    assert isinstance(track.locate(T0 + timedelta(seconds=100), max_gap_s=3600), TrackFix)


def test_capture_times_on_the_track_clock() -> None:
    naive = datetime(2024, 6, 1, 12, 0, 0)  # a camera's wall clock, no zone: read as UTC
    assert track_time(naive) == datetime(2024, 6, 1, 12, 0, 0, tzinfo=UTC)
    assert track_time(naive, -7200) == datetime(2024, 6, 1, 10, 0, 0, tzinfo=UTC), "a camera set to UTC+2"
    aware = datetime(2024, 6, 1, 12, 0, 0, tzinfo=timezone(timedelta(hours=2)))
    assert track_time(aware, 1.5) == datetime(2024, 6, 1, 10, 0, 1, 500000, tzinfo=UTC)


def test_gpx_times_without_a_zone_are_utc_and_points_without_time_are_left_out() -> None:
    text = gpx_text([(None, LAT0, LON0), *east_walk(n=3)]).replace("Z</time>", "</time>", 1)
    track = read_gpx(text.encode())
    assert len(track.points) == 3 and track.start == T0


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (b"not xml at all", "not a GPX file"),
        (gpx_text([(None, LAT0, LON0)]).encode(), "no track points with a time"),
    ],
)
def test_unreadable_tracks_say_why(content: bytes, fragment: str) -> None:
    with pytest.raises(GeotagError, match=fragment):
        read_gpx(content)


def test_mapillary_descriptions_by_relative_path_absolute_path_or_unique_name(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    entries = [
        {
            "filename": str(tmp_path / "a.jpg"),  # mapillary_tools writes absolute paths
            "MAPLatitude": 55.7,
            "MAPLongitude": "13.19",
            "MAPCaptureTime": "2014_06_07_10_24_05_656",
            "MAPCompassHeading": {"TrueHeading": 179.5, "MagneticHeading": 170.0},
            "MAPSequenceUUID": "seq-1",
        },
        {"filename": "sub/b.jpg", "MAPCompassHeading": {"MagneticHeading": 10.0}},
        {"filename": "/elsewhere/c.jpg", "MAPLatitude": 0, "MAPLongitude": 0},
        {"filename": "d.jpg", "error": {"type": "MapillaryGeoTaggingError", "message": "no GPS"}},
        "not an object",
    ]
    description = tmp_path / "mapillary_image_description.json"
    description.write_text(json.dumps(entries))
    found = read_mapillary_descriptions([description], tmp_path)
    assert len(found) == 3
    a = found.for_photo("a.jpg")
    assert a is not None and (a.lat, a.lon, a.sequence_id) == (55.7, 13.19, "seq-1")
    assert a.time == datetime(2014, 6, 7, 10, 24, 5, 656000, tzinfo=UTC)
    assert a.compass is not None and (a.compass.heading_deg, a.compass.reference) == (179.5, "true")
    b = found.for_photo("sub/b.jpg")
    assert b is not None and b.compass is not None and b.compass.reference == "magnetic-converted"
    assert b.lat is None and b.time is None and b.sequence_id is None
    c = found.for_photo("moved/c.jpg")  # not under the folder: found by its file name
    assert c is not None and c.lat is None, "0, 0 is no position"
    assert found.for_photo("d.jpg") is None, "an image mapillary_tools could not process"


def test_a_broken_description_file_says_which(tmp_path: Path) -> None:
    description = tmp_path / "mapillary_image_description.json"
    description.write_text("{not json")
    with pytest.raises(GeotagError, match="mapillary_image_description.json is not a Mapillary image description"):
        read_mapillary_descriptions([description], tmp_path)
    description.write_text('{"filename": "a.jpg"}')
    with pytest.raises(GeotagError, match="not a JSON list"):
        read_mapillary_descriptions([description], tmp_path)
