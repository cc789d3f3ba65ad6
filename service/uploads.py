"""Receiving uploaded files.

An upload is streamed to a temp file in the file store's ``tmp/`` with a size limit and a sha256, then put
under its key only as part of a successful database transaction.
"""

from __future__ import annotations

import contextlib
import hashlib
import secrets
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from fastapi import UploadFile

from db.files import FileStore
from service.errors import ApiError

CHUNK_BYTES = 1024 * 1024
STALE_TEMP_S = 3600.0


@dataclass
class ReceivedFile:
    """An upload saved to a temp file; :meth:`move_to` puts it in the store under its key."""

    path: Path
    sha256: str
    size_bytes: int
    filename: str | None
    store: FileStore
    placed: list[str] = field(default_factory=list)

    def move_to(self, key: str) -> None:
        """Put the temp file in the store as ``key`` (call inside the database transaction that records it)."""
        if self.store.put(self.path, key):
            self.placed.append(key)


@contextlib.contextmanager
def received_upload(upload: UploadFile, store: FileStore, max_bytes: int, what: str) -> Iterator[ReceivedFile]:
    """Receive an upload (:func:`receive_upload`) for the duration of a block.

    If the block fails, a file it put in the store is removed again (nothing half-stored); the temp file is
    always removed.
    """
    received = receive_upload(upload, store, max_bytes, what)
    try:
        yield received
    except BaseException:
        store.delete(*received.placed)
        raise
    finally:
        remove_quietly(received.path)


def receive_upload(upload: UploadFile, store: FileStore, max_bytes: int, what: str) -> ReceivedFile:
    """Copy an upload to a temp file in the store's temp folder; 413 past ``max_bytes``, 422 when empty."""
    path = store.temp_dir() / f"upload-{secrets.token_hex(8)}.part"
    digest = hashlib.sha256()
    size = 0
    try:
        with path.open("wb") as out:
            upload.file.seek(0)
            while chunk := upload.file.read(CHUNK_BYTES):
                size += len(chunk)
                if size > max_bytes:
                    raise ApiError(
                        413,
                        "payload_too_large",
                        f"{what} is larger than the limit of {max_bytes} bytes",
                        {"limit_bytes": max_bytes},
                    )
                digest.update(chunk)
                out.write(chunk)
        if size == 0:
            raise ApiError(422, "empty_file", f"{what} is empty")
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return ReceivedFile(path, digest.hexdigest(), size, upload.filename, store)


def remove_quietly(*paths: Path) -> None:
    """Delete files, ignoring ones already gone."""
    for path in paths:
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)


def clean_stale_temp_files(store: FileStore, older_than_s: float = STALE_TEMP_S) -> int:
    """Delete temp uploads left by a crash; returns how many."""
    removed = 0
    cutoff = time.time() - older_than_s
    for path in store.temp_dir().glob("upload-*.part"):
        try:
            if path.stat().st_mtime < cutoff:
                path.unlink()
                removed += 1
        except OSError:
            continue
    return removed


def clean_orphan_files(store: FileStore, referenced: set[str], older_than_s: float = STALE_TEMP_S) -> int:
    """Delete stored files no row refers to; returns how many.

    Such files are left by a crash between the file move and the commit, or between a delete's commit and
    the file removal. Only files older than ``older_than_s`` go, in case another API process is still
    writing one.
    """
    orphans = [key for key in store.stored_keys(older_than_s) if key not in referenced]
    store.delete(*orphans)
    return len(orphans)
