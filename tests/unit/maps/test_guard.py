"""The guards on untrusted map files: the decompressed-size limit and messages without server paths."""

from __future__ import annotations

import bz2
import gzip
import time
import zipfile
from pathlib import Path

import pytest

from geoloc.maps import MapLoadError, load_map
from geoloc.maps.guard import (
    RATIO_FLOOR_BYTES,
    DecompressedTooLargeError,
    check_decompressed_size,
    public_message,
    public_name,
)
from tests.bombs import gzip_bomb

MIB = 1024 * 1024


def test_gzip_bomb_stops_at_the_limit_not_at_its_size(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.osm.gz"
    bomb.write_bytes(gzip_bomb(3 * 1024 * MIB))  # 3 GiB of spaces inflated
    assert bomb.stat().st_size < 8 * MIB
    start = time.monotonic()
    with pytest.raises(DecompressedTooLargeError, match=r"city\.osm\.gz: decompresses to more than the limit") as error:
        check_decompressed_size(bomb, 32 * MIB, "city.osm.gz")
    assert time.monotonic() - start < 5.0  # 32 MiB inflated, not 3 GiB
    assert error.value.code == "payload_too_large" and error.value.details["limit_bytes"] == 32 * MIB
    assert isinstance(error.value, MapLoadError)
    start = time.monotonic()  # a limit as high as the bomb: its ratio stops it after RATIO_FLOOR_BYTES
    with pytest.raises(DecompressedTooLargeError, match=r"more than 500 times its size \(a decompression bomb\)"):
        check_decompressed_size(bomb, 4 * 1024 * MIB, "city.osm.gz")
    assert time.monotonic() - start < 5.0


def test_map_data_that_compresses_as_map_data_does_is_not_a_bomb(tmp_path: Path) -> None:
    rows = [f'<way id="{i}"><nd ref="{i * 7}"/><tag k="building" v="yes"/></way>\n' for i in range(1_500_000)]
    text = "".join(rows).encode()  # ~90 MB of repetitive OSM-like XML
    assert len(text) > RATIO_FLOOR_BYTES
    gz = tmp_path / "city.osm.gz"
    gz.write_bytes(gzip.compress(text, 6))
    assert check_decompressed_size(gz, 1024 * MIB, "city.osm.gz") == len(text)


def test_sizes_under_the_limit_are_counted_for_every_container(tmp_path: Path) -> None:
    inflated = b"<osm>" + b" " * (3 * MIB)
    gz = tmp_path / "a.gz"
    gz.write_bytes(gzip.compress(inflated) + gzip.compress(inflated))  # two members: both counted
    assert check_decompressed_size(gz, 1024 * MIB, "a") == 2 * len(inflated)
    with pytest.raises(DecompressedTooLargeError):
        check_decompressed_size(gz, len(inflated) + 1, "a")
    bz = tmp_path / "a.bz2"
    bz.write_bytes(bz2.compress(inflated))
    assert check_decompressed_size(bz, 4 * MIB, "a") == len(inflated)
    with pytest.raises(DecompressedTooLargeError):
        check_decompressed_size(bz, 2 * MIB, "a")
    zipped = tmp_path / "a.zip"
    with zipfile.ZipFile(zipped, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("a.shp", inflated)
        archive.writestr("a.dbf", inflated)
    assert check_decompressed_size(zipped, 8 * MIB, "a") == 2 * len(inflated)
    with pytest.raises(DecompressedTooLargeError):
        check_decompressed_size(zipped, 5 * MIB, "a")  # the members together
    plain = tmp_path / "a.osm"
    plain.write_bytes(inflated)
    assert check_decompressed_size(plain, 1, "a") is None  # not compressed: the upload limit is the limit


def test_a_broken_stream_is_left_to_the_reader(tmp_path: Path) -> None:
    broken = tmp_path / "b.gz"
    broken.write_bytes(gzip_bomb(64 * MIB)[:5000] + b"\x00garbage" * 100)
    assert check_decompressed_size(broken, 1024 * MIB, "b") is not None


def test_a_broken_zipped_shapefile_says_so_without_a_server_path(tmp_path: Path) -> None:
    upload = tmp_path / "store" / "tmp" / "upload-0123456789abcdef.part"
    upload.parent.mkdir(parents=True)
    with zipfile.ZipFile(upload, "w") as archive:
        archive.writestr("roads/buildings.shp", b"\x00\x00\x27\x0a" + b"not a shapefile" * 20)
        archive.writestr("roads/buildings.dbf", b"junk")
    with pytest.raises(Exception) as error:  # noqa: PT011  # whatever the reader raises, its message is checked
        load_map(upload)
    shown = public_message(str(error.value), upload, "city.zip")
    assert str(tmp_path) not in shown and "upload-" not in shown and "/vsizip/" not in shown
    assert shown.startswith("city.zip: cannot read the zipped Shapefile") and "city.zip/roads/buildings.shx" in shown


def test_public_message_hides_every_absolute_path() -> None:
    path = Path("/srv/geoloc/data/files/tmp/upload-ab12.part")
    text = f"{path}: bad; /vsizip/{{{path}}}/x.shp; also /var/lib/other/file.dbf and {path.name}"
    shown = public_message(text, path, "town.zip")
    assert "/srv" not in shown and "/var" not in shown and "upload-ab12" not in shown
    assert shown.startswith("town.zip: bad; town.zip/x.shp; also <path> and town.zip"), shown
    assert public_message("WGS84 lon/lat, 1/2 of it", path, "t") == "WGS84 lon/lat, 1/2 of it"
    assert public_name("C:\\Users\\me\\maps\\city.osm") == "city.osm" and public_name("/home/x/a.gpkg") == "a.gpkg"
    assert public_name(None) == "the file" and public_name("  ") == "the file"
