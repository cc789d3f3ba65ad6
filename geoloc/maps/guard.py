"""Guards on untrusted map files: a decompressed-size limit, and error messages without server paths.

:func:`check_decompressed_size` inflates a ``.gz``/``.bz2`` file or every member of a zip archive once,
counting bytes and keeping none, and stops with :class:`DecompressedTooLargeError` as soon as the count passes
the limit, or passes :data:`MAX_RATIO` times the compressed bytes read (past :data:`RATIO_FLOOR_BYTES`): a 2 MB
gzip of 3 GB of spaces is refused after inflating 64 MB, not 3 GB nor the limit (inflating runs at a few
hundred MB/s on a busy core). The declared sizes (gzip's trailer, zip headers) are never trusted.
A stream that is broken is not this guard's business: counting stops quietly and the reader reports it.

:func:`public_message` rewrites a reader's message for the user: the file's server path (a temp upload, the
file store) becomes the name the user gave the file (GDAL's ``/vsizip/{<upload>}/x.shp`` reads
``city.zip/x.shp``), and any other absolute path left (a library's own) becomes ``<path>``.
"""

from __future__ import annotations

import bz2
import re
import zipfile
import zlib
from pathlib import Path

from geoloc.maps.model import MapLoadError

_CHUNK_BYTES = 1 << 16
_OUT_BYTES = 1 << 22
_GZIP_MAGIC = b"\x1f\x8b"
_BZ2_MAGIC = b"BZh"
_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")
_GDAL_WRAPPED = re.compile(r"/vsi[a-z]+/\{([^}]*)\}")
_GDAL_PREFIX = re.compile(r"/vsi[a-z]+/")
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~}-])/(?:[^\s/'\"{}():,;]+/)+[^\s/'\"{}():,;]*")


MAX_RATIO = 500
"""Most decompressed bytes per compressed byte, checked past :data:`RATIO_FLOOR_BYTES` inflated. Map data compresses
10-30 times (OSM XML, GeoJSON, a Shapefile's padded .dbf up to about 100); a bomb of spaces, 1,000 (gzip) to
millions (bzip2). It refuses a bomb after :data:`RATIO_FLOOR_BYTES` however high the size limit is set."""
RATIO_FLOOR_BYTES = 64 * 1024 * 1024
"""Inflated bytes after which :data:`MAX_RATIO` is checked (small files may compress as they like)."""


class DecompressedTooLargeError(MapLoadError):
    """A compressed map inflates past the limit, or :data:`MAX_RATIO` times its size (``details``: the limits)."""

    def __init__(self, shown_name: str, limit_bytes: int, *, ratio: bool = False) -> None:
        why = f"{MAX_RATIO} times its size (a decompression bomb)" if ratio else f"the limit of {limit_bytes} bytes"
        super().__init__(
            f"{shown_name}: decompresses to more than {why}",
            code="payload_too_large",
            details={"limit_bytes": limit_bytes, "max_ratio": MAX_RATIO},
        )


def _check(total: int, consumed: int, limit_bytes: int, shown_name: str) -> None:
    """Raise :class:`DecompressedTooLargeError` when ``total`` inflated bytes (from ``consumed``) are too many."""
    if total > limit_bytes:
        raise DecompressedTooLargeError(shown_name, limit_bytes)
    if total > RATIO_FLOOR_BYTES and total > MAX_RATIO * max(consumed, 1):
        raise DecompressedTooLargeError(shown_name, limit_bytes, ratio=True)


def check_decompressed_size(path: Path, limit_bytes: int, shown_name: str) -> int | None:
    """Inflate a compressed map file once, keeping nothing; raise :class:`DecompressedTooLargeError` past the limit.

    path: the file (told by its magic bytes: gzip, bzip2, zip; anything else is not inflated, None returned).
    limit_bytes: the most decompressed bytes allowed (a zip: all members together). shown_name: the file's
    name in the message. Returns the decompressed size counted (up to where a broken stream stopped).
    """
    with path.open("rb") as f:
        head = f.read(4)
    if head.startswith(_GZIP_MAGIC):
        return _count_zlib(path, limit_bytes, shown_name, wbits=31)
    if head.startswith(_BZ2_MAGIC):
        return _count_bz2(path, limit_bytes, shown_name)
    if head.startswith(_ZIP_MAGICS):
        return _count_zip(path, limit_bytes, shown_name)
    return None


def _count_zlib(path: Path, limit_bytes: int, shown_name: str, wbits: int) -> int:
    """Decompressed size of a (multi-member) gzip file, bounded by ``limit_bytes``."""
    total = 0
    inflater = zlib.decompressobj(wbits)
    try:
        with path.open("rb") as f:
            while data := f.read(_CHUNK_BYTES):
                while data:
                    total += len(inflater.decompress(data, _OUT_BYTES))
                    _check(total, f.tell(), limit_bytes, shown_name)
                    data = inflater.unconsumed_tail
                    if inflater.eof:  # a next gzip member follows
                        data = inflater.unused_data
                        inflater = zlib.decompressobj(wbits)
    except zlib.error:
        pass  # broken stream: the reader says so
    return total


def _count_bz2(path: Path, limit_bytes: int, shown_name: str) -> int:
    """Decompressed size of a (multi-stream) bzip2 file, bounded by ``limit_bytes``."""
    total = 0
    try:
        with path.open("rb") as raw, bz2.BZ2File(raw, "rb") as f:
            while chunk := f.read(_OUT_BYTES):
                total += len(chunk)
                _check(total, raw.tell(), limit_bytes, shown_name)
    except DecompressedTooLargeError:
        raise
    except (OSError, EOFError, ValueError):
        pass  # broken stream: the reader says so
    return total


def _count_zip(path: Path, limit_bytes: int, shown_name: str) -> int:
    """Decompressed size of all members of a zip archive, bounded by ``limit_bytes``."""
    total = 0
    try:
        with path.open("rb") as raw, zipfile.ZipFile(raw) as archive:
            for info in archive.infolist():
                if info.is_dir():
                    continue
                with archive.open(info) as member:
                    while chunk := member.read(_OUT_BYTES):
                        total += len(chunk)
                        _check(total, raw.tell(), limit_bytes, shown_name)
    except DecompressedTooLargeError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, NotImplementedError, zlib.error):
        pass  # broken archive: the reader says so
    return total


def public_name(filename: str | None) -> str:
    """The name to show for an uploaded file: its base name as the user sent it (no folders), or ``the file``."""
    name = (filename or "").replace("\\", "/").rsplit("/", 1)[-1].strip()
    return name or "the file"


def public_message(message: str, path: Path, shown_name: str) -> str:
    """``message`` without server paths: ``path`` (any spelling) -> ``shown_name``, other ones -> ``<path>``."""
    message = _GDAL_PREFIX.sub("", _GDAL_WRAPPED.sub(r"\1", message))  # /vsizip/{/a/b.zip}/x.shp -> /a/b.zip/x.shp
    spellings = {str(path.resolve()), str(path), path.name}
    for spelling in sorted(spellings, key=len, reverse=True):
        message = message.replace(spelling, shown_name)
    return _ABSOLUTE_PATH.sub("<path>", message)
