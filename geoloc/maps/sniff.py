"""Which map format a file holds, told from its content (never from its name).

Formats: OSM XML (plain, ``.bz2``, ``.gz``), OSM PBF, GeoJSON (plain or ``.gz``), GeoPackage,
FlatGeobuf and a zip archive holding one or more shapefiles. A file that is none of these raises
:class:`MapLoadError` saying what it looks like instead; so do broken compressed streams, with a
message that says so (:func:`check_compressed_stream`), rather than the reader's own.
"""

from __future__ import annotations

import bz2
import gzip
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from geoloc.maps.model import MapLoadError

OSM_FORMATS = ("osm", "osm.bz2", "osm.gz", "pbf")
GIS_FORMATS = ("geojson", "geojson.gz", "gpkg", "fgb", "shapefile.zip")
FORMAT_NAMES = {
    "osm": "OSM XML",
    "osm.bz2": "bzip2-compressed OSM XML",
    "osm.gz": "gzip-compressed OSM XML",
    "pbf": "OSM PBF",
    "geojson": "GeoJSON",
    "geojson.gz": "gzip-compressed GeoJSON",
    "gpkg": "GeoPackage",
    "fgb": "FlatGeobuf",
    "shapefile.zip": "zipped Shapefile",
}
ACCEPTED = (
    "OSM XML (.osm, .osm.bz2, .osm.gz), .osm.pbf, GeoJSON (.geojson, .geojson.gz), "
    "GeoPackage (.gpkg), FlatGeobuf (.fgb) or a zipped Shapefile (.zip)"
)
_HEAD_BYTES = 4096
_CHUNK_BYTES = 1 << 20
_GPKG_APPLICATION_ID = b"GPKG"
_SHAPEFILE_MAGIC = b"\x00\x00\x27\x0a"


def sniff_format(path: Path) -> str:
    """The format of the map file at ``path`` (one of :data:`OSM_FORMATS` + :data:`GIS_FORMATS`)."""
    with path.open("rb") as f:
        head = f.read(_HEAD_BYTES)
    container_format = _container_format(path, head)
    if container_format is not None:
        return container_format
    text_format = _text_format(head)
    if text_format == "xml":
        raise MapLoadError(f"{path.name}: XML but not OpenStreetMap data (no <osm> element)")
    if text_format:
        return text_format
    if b"OSMHeader" in head[:64]:
        return "pbf"
    raise MapLoadError(f"{path.name}: not map data (expected {ACCEPTED})")


def _container_format(path: Path, head: bytes) -> str | None:
    """The format of a compressed, zipped or database file from its magic bytes; None for other files.

    Raises :class:`MapLoadError` for containers that hold no map (another SQLite database, a bare .shp).
    """
    if head.startswith(b"\x1f\x8b"):
        return _compressed_text_format(path, "gz", _decompressed_head(path, gzip.open))
    if head.startswith(b"BZh"):
        return _compressed_text_format(path, "bz2", _decompressed_head(path, bz2.open))
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return _zip_format(path)
    if head.startswith(b"SQLite format 3\x00"):
        if head[68:72] == _GPKG_APPLICATION_ID:
            return "gpkg"
        raise MapLoadError(f"{path.name}: an SQLite database that is not a GeoPackage (expected {ACCEPTED})")
    if head[:3] == b"fgb" and head[4:7] == b"fgb":
        return "fgb"
    if head.startswith(_SHAPEFILE_MAGIC) and len(head) >= 100:
        raise MapLoadError(
            f"{path.name}: a bare shapefile (.shp) has no attributes and no CRS on its own; "
            "upload it zipped together with its .shx, .dbf and .prj files"
        )
    return None


def _text_format(head: bytes) -> str | None:
    """``osm``, ``geojson``, ``xml`` (other XML) or None, from the first bytes of a text file."""
    stripped = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if stripped.startswith(b"<"):
        return "osm" if b"<osm" in head else "xml"
    if stripped.startswith(b"{"):
        return "geojson"
    return None


def _decompressed_head(path: Path, opener: Callable[..., Any]) -> bytes:
    try:
        with opener(path, "rb") as f:
            return bytes(f.read(_HEAD_BYTES))
    except (OSError, EOFError, ValueError, zlib.error) as exc:
        raise MapLoadError(f"{path.name}: a compressed file that cannot be decompressed ({exc})") from exc


def _compressed_text_format(path: Path, compression: str, inner: bytes) -> str:
    kind = _text_format(inner)
    if kind in ("osm", "geojson"):
        return f"{kind}.{compression}"
    what = "gzip" if compression == "gz" else "bz2"
    raise MapLoadError(f"{path.name}: a {what} file that holds neither OSM XML nor GeoJSON (expected {ACCEPTED})")


def _zip_format(path: Path) -> str:
    names = zip_member_names(path)
    if not any(name.lower().endswith(".shp") for name in names):
        shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "") if names else "nothing"
        raise MapLoadError(
            f"{path.name}: a zip archive without a shapefile (.shp); it holds {shown}",
            details={"zip_members": names[:100]},
        )
    return "shapefile.zip"


def zip_member_names(path: Path) -> list[str]:
    """File names inside a zip archive (no folders), or :class:`MapLoadError` if it cannot be read."""
    try:
        with zipfile.ZipFile(path) as archive:
            return [info.filename for info in archive.infolist() if not info.is_dir()]
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        raise MapLoadError(f"{path.name}: a zip archive that cannot be read ({exc})") from exc


def check_compressed_stream(path: Path, kind: str) -> None:
    """Raise :class:`MapLoadError` if the gzip/bz2 stream of a ``*.gz``/``*.bz2`` file is broken.

    Truncated or corrupt: the stream is read to the end, nothing kept. Called when a reader fails, to
    say what went wrong.
    """
    compression = kind.rsplit(".", 1)[-1]
    if compression not in ("gz", "bz2"):
        return
    opener: Callable[..., Any] = gzip.open if compression == "gz" else bz2.open
    try:
        with opener(path, "rb") as f:
            while f.read(_CHUNK_BYTES):
                pass
    except (OSError, EOFError, ValueError, zlib.error) as exc:
        what = "gzip" if opener is gzip.open else "bzip2"
        raise MapLoadError(f"{path.name}: the {what} stream is truncated or corrupt ({exc})") from exc
