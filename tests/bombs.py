"""Compressed map files that inflate far past their size, built in well under a second without writing it all.

A gzip file may hold several members one after the other (RFC 1952), each a gzip stream of its own: one member
of 64 MiB of spaces (about 64 KB compressed) repeated makes a file that inflates to ``repeat x 64 MiB``.
"""

from __future__ import annotations

import gzip
import zlib
from pathlib import Path

MEMBER_BYTES = 64 * 1024 * 1024
"""What one repeated gzip member inflates to."""


def gzip_bomb(inflated_bytes: int, head: bytes = b"<?xml version='1.0'?>\n<osm version='0.6'>\n") -> bytes:
    """A multi-member gzip file that inflates to ``head`` + at least ``inflated_bytes`` of spaces (OSM XML's start)."""
    compressor = zlib.compressobj(9, zlib.DEFLATED, 31)
    spaces = b" " * (1 << 20)
    member = b"".join(compressor.compress(spaces) for _ in range(MEMBER_BYTES // len(spaces))) + compressor.flush()
    repeat = -(-inflated_bytes // MEMBER_BYTES)
    return gzip.compress(head) + member * repeat


def write_gzip_bomb(path: Path, inflated_bytes: int) -> Path:
    """:func:`gzip_bomb` written to ``path`` (a few MB for gigabytes inflated)."""
    path.write_bytes(gzip_bomb(inflated_bytes))
    return path
