"""Named numpy arrays in one file that processes open memory-mapped: read-only pages shared through the page cache.

:func:`write_arrays` writes an uncompressed ``.npz`` (a zip of ``.npy`` members, no pickle) atomically: a reader
sees the old file, none, or the whole new one. :func:`map_arrays` opens it without reading it: each member is a
read-only ``np.memmap`` view at its offset in the file, so opening costs microseconds whatever the size, a page
is read from disk only when touched, and every process that maps the same file shares the same physical pages
(the kernel's page cache) instead of holding its own copy. The file stays a valid ``.npz`` (``np.load`` reads it).

Replacing a file that another process has mapped is safe: ``os.replace`` gives the new file a new inode and the
old mapping keeps the old pages until it is dropped.
"""

from __future__ import annotations

import mmap
import os
import secrets
import struct
import zipfile
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

_LOCAL_HEADER = struct.Struct("<4sHHHHHIIIHH")
"""A zip member's local file header (its name and extra field follow): 30 bytes."""
_LOCAL_MAGIC = b"PK\x03\x04"


def write_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` (name -> array; names without ``/``) to ``path`` as an uncompressed ``.npz``, atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    try:
        with temp.open("wb") as out:
            members: dict[str, Any] = {name: np.asarray(a) for name, a in arrays.items()}
            np.savez(out, **members)
        os.replace(temp, path)
    finally:
        temp.unlink(missing_ok=True)


def map_arrays(path: Path) -> dict[str, np.ndarray]:
    """The arrays of a file :func:`write_arrays` wrote, each a read-only view of the file's pages.

    ``ValueError`` when the file is not such a file (not a zip, a compressed member, an object array).
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive, path.open("rb") as raw:
            members = archive.infolist()
            places = [_member_data(raw, info) for info in members]
    except (OSError, zipfile.BadZipFile, EOFError, struct.error) as exc:
        raise ValueError(f"{path.name}: not an array file ({exc})") from exc
    out: dict[str, np.ndarray] = {}
    for info, (offset, dtype, shape, fortran) in zip(members, places, strict=True):
        name = info.filename.removesuffix(".npy")
        if int(np.prod(shape)) == 0:
            array = np.zeros(shape, dtype)
        else:
            mapped = np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C")
            array = np.asarray(mapped).reshape(shape)
        array.flags.writeable = False
        out[name] = array
    return out


def is_mapped(array: np.ndarray) -> bool:
    """Whether ``array`` is a view of a memory-mapped file (its chain of bases ends in an ``mmap``)."""
    base: object = array
    while isinstance(base, np.ndarray):
        base = base.base
    return isinstance(base, mmap.mmap)


def _member_data(raw: BinaryIO, info: zipfile.ZipInfo) -> tuple[int, np.dtype[np.generic], tuple[int, ...], bool]:
    """Where a stored ``.npy`` member's data starts in the file, its dtype, shape and order."""
    if info.compress_type != zipfile.ZIP_STORED:
        raise ValueError(f"member {info.filename} is compressed")
    raw.seek(info.header_offset)
    fields = _LOCAL_HEADER.unpack(raw.read(_LOCAL_HEADER.size))
    if fields[0] != _LOCAL_MAGIC:
        raise ValueError(f"member {info.filename}: no local header")
    name_len, extra_len = fields[9], fields[10]
    start = info.header_offset + _LOCAL_HEADER.size + name_len + extra_len
    raw.seek(start)
    version = np.lib.format.read_magic(raw)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(raw)
    else:
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(raw)
    if dtype.hasobject:
        raise ValueError(f"member {info.filename} holds Python objects")
    return int(raw.tell()), dtype, tuple(shape), bool(fortran)
