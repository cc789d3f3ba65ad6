"""EXIF reading and writing: round trip, real phone photos, missing and malformed metadata."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from contracts.settings import shared_dir
from geoloc.photos.exif import ExifFields, read_exif, write_jpeg

LUND = shared_dir() / "data" / "lund"


def _rgb(h: int = 48, w: int = 64) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)


@pytest.mark.parametrize(("lat", "lon"), [(60.1699123, 24.9384456), (-33.8688197, -151.2092955), (0.5, -0.25)])
def test_round_trip(tmp_path: Path, lat: float, lon: float) -> None:
    fields = ExifFields(
        lat=lat, lon=lon, focal_35mm=31, focal_mm=4.43, altitude=-3.5, heading_deg=123.45, make="Acme", model="Phone 9"
    )
    path = write_jpeg(tmp_path / "a.jpg", _rgb(), fields)
    info = read_exif(path)
    assert info.lat == pytest.approx(lat, abs=1e-9)
    assert info.lon == pytest.approx(lon, abs=1e-9)
    assert info.altitude == pytest.approx(-3.5)
    assert info.focal_35mm == 31
    assert info.focal_mm == pytest.approx(4.43)
    assert info.heading_deg == pytest.approx(123.45)
    assert (info.make, info.model, info.width, info.height, info.orientation) == ("Acme", "Phone 9", 64, 48, 1)
    assert info.datetime is not None
    assert read_exif(path.read_bytes()) == info  # bytes and paths agree


def test_missing_gps_is_none(tmp_path: Path) -> None:
    info = read_exif(write_jpeg(tmp_path / "b.jpg", _rgb(), ExifFields(focal_35mm=26)))
    assert info.lat is None and info.lon is None and not info.has_gps
    assert info.focal_35mm == 26
    buf = io.BytesIO()
    Image.fromarray(_rgb()).save(buf, "JPEG")  # no EXIF at all
    plain = read_exif(buf.getvalue())
    assert not plain.has_gps and plain.focal_35mm is None and (plain.width, plain.height) == (64, 48)


@pytest.mark.parametrize("data", [b"", b"not an image", b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00garbage!"])
def test_malformed_never_raises(data: bytes) -> None:
    info = read_exif(data)
    assert info.lat is None


def test_truncated_and_corrupted(tmp_path: Path) -> None:
    data = write_jpeg(tmp_path / "c.jpg", _rgb(), ExifFields(lat=60.0, lon=25.0, focal_35mm=31)).read_bytes()
    for cut in (20, 200, len(data) // 2):
        read_exif(data[:cut])  # must not raise
    corrupted = bytearray(data)
    corrupted[40:80] = b"\xff" * 40
    read_exif(bytes(corrupted))


@pytest.mark.skipif(not (LUND / "gps.csv").exists(), reason="shared Lund photos not available")
def test_real_iphone_photos_match_gps_csv() -> None:
    rows = list(csv.DictReader((LUND / "gps.csv").open()))
    assert rows
    for row in rows:
        info = read_exif(LUND / "images" / row["name"])
        assert info.lat == pytest.approx(float(row["lat"]), abs=1e-6), row["name"]
        assert info.lon == pytest.approx(float(row["lon"]), abs=1e-6), row["name"]
        assert info.altitude == pytest.approx(float(row["alt"]), abs=1.0)
        assert info.focal_35mm and info.focal_35mm > 0
        assert info.width and info.height
