"""Capture reading: the Lund walk and the Berlin photos as they are, and JPEGs written here with edge cases."""

from __future__ import annotations

import csv
import json
import math
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np
import piexif
import pytest
from PIL import Image

from contracts.settings import shared_dir
from geoloc.photos.capture import DECLINATION_BOUND_DEG, CaptureInfo, CompassReading, read_capture
from geoloc.photos.exif import read_exif
from geoloc.photos.photo import load_photo

DATA = shared_dir() / "data"
LUND = sorted((DATA / "lund" / "images").glob("*.jpg"))
BERLIN = DATA / "berlin"


def _jpeg(
    path: Path,
    *,
    zeroth: dict[int, Any] | None = None,
    exif: dict[int, Any] | None = None,
    gps: dict[int, Any] | None = None,
) -> Path:
    """A small JPEG carrying exactly the given EXIF tags (piexif ids)."""
    block = piexif.dump({"0th": zeroth or {}, "Exif": exif or {}, "GPS": gps or {}, "1st": {}, "thumbnail": None})
    rgb = np.random.default_rng(1).integers(0, 255, (32, 48, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(path, "JPEG", exif=block)
    return path


def _mapillary(**compass: Any) -> bytes:
    meta = {"MAPCompassHeading": compass, "MAPCaptureTime": "2016_03_14_13_02_45_123", "MAPSequenceUUID": "S-1"}
    return json.dumps(meta).encode()


@pytest.mark.skipif(len(LUND) != 29, reason="needs shared/data/lund/images")
def test_lund_photos_read_as_one_walk() -> None:
    captures = [read_capture(path) for path in LUND]
    assert {c.sequence_id for c in captures} == {"0F3F9BEF-DC5B-4704-9435-C18EC44702C9"}
    assert len({c.photo_id for c in captures}) == 29 and None not in {c.photo_id for c in captures}
    times = [c.time for c in captures]
    assert all(t is not None and t.tzinfo is not None for t in times)  # Mapillary's UTC time: no EXIF time here
    assert all(c.time_source == "mapillary" for c in captures)
    assert all(b > a for a, b in zip(times, times[1:], strict=False))  # type: ignore[operator]
    assert times[0] == datetime(2014, 6, 7, 10, 24, 5, 656000, tzinfo=UTC)
    for path, capture in zip(LUND, captures, strict=True):
        meta = json.loads(piexif.load(str(path))["0th"][piexif.ImageIFD.ImageDescription])
        stated = meta["MAPCompassHeading"]
        compass = capture.compass
        assert compass is not None and (compass.source, compass.reference) == ("mapillary", "true")
        assert 0.0 <= compass.heading_deg < 360.0
        assert compass.heading_deg == pytest.approx(stated["TrueHeading"])
        assert compass.accuracy_deg == stated["AccuracyDegrees"]
        assert capture.gps_accuracy_m == float(meta["MAPGPSAccuracyMeters"])  # no GPSHPositioningError here
    assert {c.gps_accuracy_m for c in captures} == {5.0, 10.0}
    assert load_photo(LUND[0]).capture == captures[0]  # the loader carries it


@pytest.mark.skipif(not (BERLIN / "exif_gps_heading.csv").is_file(), reason="needs shared/data/berlin")
def test_berlin_headings_match_the_table() -> None:
    with (BERLIN / "exif_gps_heading.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3
    for row in rows:
        path = BERLIN / "images" / row["name"]
        capture = read_capture(path)
        assert read_exif(path).heading_deg is None  # no GPSImgDirection: the compass is Mapillary's JSON
        assert capture.compass is not None and capture.compass.source == "mapillary"
        delta = (capture.compass.heading_deg - float(row["true_heading_deg"]) + 180.0) % 360.0 - 180.0
        assert abs(delta) < 1.0
        assert capture.compass.accuracy_deg == float(row["heading_accuracy_deg"])
        assert capture.time == datetime.strptime(row["map_capture_time"] + "000", "%Y_%m_%d_%H_%M_%S_%f").replace(
            tzinfo=UTC
        )
    assert len({read_capture(BERLIN / "images" / r["name"]).sequence_id for r in rows}) == 1


def test_exif_true_heading_subseconds_and_offset(tmp_path: Path) -> None:
    path = _jpeg(
        tmp_path / "a.jpg",
        exif={
            piexif.ExifIFD.DateTimeOriginal: b"2021:07:04 18:30:15",
            piexif.ExifIFD.SubSecTimeOriginal: b"042",
            piexif.ExifIFD.OffsetTimeOriginal: b"-05:00",
        },
        gps={piexif.GPSIFD.GPSImgDirectionRef: b"T", piexif.GPSIFD.GPSImgDirection: (27125, 100)},
    )
    capture = read_capture(path)
    assert capture.compass == CompassReading(271.25, None, "exif", "true")
    assert capture.time == datetime(2021, 7, 4, 18, 30, 15, 42000, tzinfo=timezone(timedelta(hours=-5)))
    assert capture.time_source == "exif" and capture.sequence_id is None
    assert read_capture(path.read_bytes()) == capture


def test_exif_without_offset_is_naive_and_mapillary_utc_wins(tmp_path: Path) -> None:
    naive = {piexif.ExifIFD.DateTimeOriginal: b"2016:03:14 14:02:45", piexif.ExifIFD.SubSecTimeOriginal: b"5"}
    only_exif = read_capture(_jpeg(tmp_path / "a.jpg", exif=naive))
    assert only_exif.time == datetime(2016, 3, 14, 14, 2, 45, 500000) and only_exif.time_source == "exif"
    both = read_capture(
        _jpeg(tmp_path / "b.jpg", zeroth={piexif.ImageIFD.ImageDescription: _mapillary(TrueHeading=10)}, exif=naive)
    )
    assert both.time == datetime(2016, 3, 14, 13, 2, 45, 123000, tzinfo=UTC)
    assert both.time_source == "mapillary" and both.sequence_id == "S-1"


def test_magnetic_headings_are_kept_with_a_widened_accuracy(tmp_path: Path) -> None:
    exif_m = read_capture(
        _jpeg(tmp_path / "m.jpg", gps={piexif.GPSIFD.GPSImgDirectionRef: b"M", piexif.GPSIFD.GPSImgDirection: (90, 1)})
    )
    assert exif_m.compass == CompassReading(90.0, DECLINATION_BOUND_DEG, "exif", "magnetic-converted")
    no_ref = read_capture(_jpeg(tmp_path / "n.jpg", gps={piexif.GPSIFD.GPSImgDirection: (90, 1)}))
    assert no_ref.compass is not None and no_ref.compass.reference == "magnetic-converted"
    declined = read_capture(tmp_path / "m.jpg", declination_deg=-4.5).compass
    assert declined == CompassReading(85.5, None, "exif", "magnetic-converted")
    description = {piexif.ImageIFD.ImageDescription: _mapillary(MagneticHeading=200.0, AccuracyDegrees=15)}
    mapillary_m = read_capture(_jpeg(tmp_path / "j.jpg", zeroth=description)).compass
    assert mapillary_m is not None and (mapillary_m.source, mapillary_m.reference) == (
        "mapillary",
        "magnetic-converted",
    )
    assert mapillary_m.heading_deg == 200.0 and mapillary_m.accuracy_deg == pytest.approx(math.hypot(15, 25))


def test_preference_mapillary_true_then_exif_true(tmp_path: Path) -> None:
    gps_t = {piexif.GPSIFD.GPSImgDirectionRef: b"T", piexif.GPSIFD.GPSImgDirection: (45, 1)}
    both = _mapillary(TrueHeading=300.5, MagneticHeading=296.0, AccuracyDegrees=12)
    compass = read_capture(_jpeg(tmp_path / "a.jpg", zeroth={270: both}, gps=gps_t)).compass
    assert compass == CompassReading(300.5, 12.0, "mapillary", "true")
    magnetic_only = _mapillary(MagneticHeading=296.0, AccuracyDegrees=12)
    compass = read_capture(_jpeg(tmp_path / "b.jpg", zeroth={270: magnetic_only}, gps=gps_t)).compass
    assert compass == CompassReading(45.0, None, "exif", "true")  # a true EXIF heading beats a magnetic one


@pytest.mark.parametrize(
    ("description", "gps", "expected"),
    [
        (b"not json {", {}, CaptureInfo()),  # a plain-text description
        (b'{"MAPCompassHeading": [1, 2]', {}, CaptureInfo()),  # broken JSON
        (b"[1, 2, 3]", {}, CaptureInfo()),  # JSON but not an object
        (_mapillary(TrueHeading=412.0, AccuracyDegrees=10), {}, None),  # out of range
        (_mapillary(TrueHeading=-1.0, AccuracyDegrees=10), {}, None),  # iOS "invalid"
        (_mapillary(TrueHeading="NaN", AccuracyDegrees=10), {}, None),
        (_mapillary(TrueHeading=10.0, AccuracyDegrees=-1), {}, None),  # iOS: heading invalid
        (b"x", {piexif.GPSIFD.GPSImgDirectionRef: b"T", piexif.GPSIFD.GPSImgDirection: (720, 1)}, CaptureInfo()),
        (b"x", {piexif.GPSIFD.GPSImgDirectionRef: b"T", piexif.GPSIFD.GPSImgDirection: (1, 0)}, CaptureInfo()),
    ],
)
def test_malformed_values_are_ignored(
    tmp_path: Path, description: bytes, gps: dict[int, Any], expected: CaptureInfo | None
) -> None:
    capture = read_capture(_jpeg(tmp_path / "a.jpg", zeroth={270: description}, gps=gps))
    assert capture.compass is None
    if expected is not None:
        assert capture == expected
    else:  # the rest of the JSON is still read
        assert capture.sequence_id == "S-1" and capture.time is not None


def test_zero_accuracy_keeps_the_heading_without_accuracy(tmp_path: Path) -> None:
    capture = read_capture(_jpeg(tmp_path / "a.jpg", zeroth={270: _mapillary(TrueHeading=360.0, AccuracyDegrees=0)}))
    assert capture.compass == CompassReading(0.0, None, "mapillary", "true")


def test_gps_accuracy_exif_first_then_mapillary(tmp_path: Path) -> None:
    meta = json.dumps({"MAPGPSAccuracyMeters": "5.000000"}).encode()
    zeroth = {piexif.ImageIFD.ImageDescription: meta}
    both = _jpeg(tmp_path / "both.jpg", zeroth=zeroth, gps={piexif.GPSIFD.GPSHPositioningError: (65, 10)})
    assert read_capture(both).gps_accuracy_m == 6.5
    assert read_capture(_jpeg(tmp_path / "map.jpg", zeroth=zeroth)).gps_accuracy_m == 5.0
    assert read_capture(_jpeg(tmp_path / "none.jpg")).gps_accuracy_m is None
    for i, bad in enumerate([(0, 1), (5, 0), (20_000, 1)]):  # no accuracy, a zero denominator, not a fix's error
        path = _jpeg(tmp_path / f"bad{i}.jpg", zeroth=zeroth, gps={piexif.GPSIFD.GPSHPositioningError: bad})
        assert read_capture(path).gps_accuracy_m == 5.0  # the Mapillary reading instead
    for i, text in enumerate(["-1", "nan", "ten", "0"]):
        path = _jpeg(
            tmp_path / f"m{i}.jpg",
            zeroth={piexif.ImageIFD.ImageDescription: f'{{"MAPGPSAccuracyMeters": "{text}"}}'.encode()},
        )
        assert read_capture(path).gps_accuracy_m is None


@pytest.mark.parametrize(
    "exif",
    [
        {piexif.ExifIFD.DateTimeOriginal: b"2016:13:40 25:61:00"},  # no such date
        {piexif.ExifIFD.DateTimeOriginal: b"    :  :     :  :  "},  # what some cameras write for "unknown"
    ],
)
def test_malformed_times_are_ignored(tmp_path: Path, exif: dict[int, Any]) -> None:
    assert read_capture(_jpeg(tmp_path / "a.jpg", exif=exif)).time is None


def test_bad_subseconds_and_offsets_are_left_out(tmp_path: Path) -> None:
    exif = {
        piexif.ExifIFD.DateTimeOriginal: b"2020:01:02 03:04:05",
        piexif.ExifIFD.SubSecTimeOriginal: b"ab",
        piexif.ExifIFD.OffsetTimeOriginal: b"+99:00",
    }
    assert read_capture(_jpeg(tmp_path / "a.jpg", exif=exif)).time == datetime(2020, 1, 2, 3, 4, 5)


@pytest.mark.parametrize("data", [b"", b"not an image", b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00garbage!"])
def test_never_raises(data: bytes) -> None:
    assert read_capture(data) == CaptureInfo()
