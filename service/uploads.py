"""Receiving uploaded files.

Streamed to a temp file under ``DATA_DIR/tmp`` with a size limit and a sha256, then moved into
place only as part of a successful database transaction.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from fastapi import UploadFile

from service.errors import ApiError

CHUNK_BYTES = 1024 * 1024
STALE_TEMP_S = 3600.0


@dataclass
class ReceivedFile:
    """An upload saved to a temp file; :meth:`move_to` puts it in its final place."""

    path: Path
    sha256: str
    size_bytes: int
    filename: str | None
    placed: list[Path] = field(default_factory=list)

    def move_to(self, final_path: Path) -> None:
        """Move the temp file to ``final_path`` (call inside the database transaction that records it)."""
        if move_into_place(self.path, final_path):
            self.placed.append(final_path)


@contextlib.contextmanager
def received_upload(upload: UploadFile, data_dir: Path, max_bytes: int, what: str) -> Iterator[ReceivedFile]:
    """Receive an upload (:func:`receive_upload`) for the duration of a block.

    If the block fails, a file it moved into place is removed again (nothing half-stored); the temp
    file is always removed.
    """
    received = receive_upload(upload, data_dir, max_bytes, what)
    try:
        yield received
    except BaseException:
        remove_quietly(*received.placed)
        raise
    finally:
        remove_quietly(received.path)


def temp_dir(data_dir: Path) -> Path:
    """``DATA_DIR/tmp`` (same file system as the final place, so the move is a rename)."""
    path = data_dir / "tmp"
    path.mkdir(parents=True, exist_ok=True)
    return path


def receive_upload(upload: UploadFile, data_dir: Path, max_bytes: int, what: str) -> ReceivedFile:
    """Copy an upload to a temp file; 413 past ``max_bytes``, 422 when empty."""
    path = temp_dir(data_dir) / f"upload-{secrets.token_hex(8)}.part"
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
    return ReceivedFile(path, digest.hexdigest(), size, upload.filename)


def move_into_place(temp_path: Path, final_path: Path) -> bool:
    """Rename ``temp_path`` to ``final_path``; True if that created the file.

    False: the same content was already there. Call inside the database transaction; on failure
    delete it again.
    """
    final_path.parent.mkdir(parents=True, exist_ok=True)
    existed = final_path.exists()
    os.replace(temp_path, final_path)
    return not existed


def remove_quietly(*paths: Path) -> None:
    """Delete files, ignoring ones already gone."""
    for path in paths:
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)


def clean_stale_temp_files(data_dir: Path, older_than_s: float = STALE_TEMP_S) -> int:
    """Delete temp uploads left by a crash; returns how many."""
    removed = 0
    cutoff = time.time() - older_than_s
    for path in temp_dir(data_dir).glob("upload-*.part"):
        try:
            if path.stat().st_mtime < cutoff:
                path.unlink()
                removed += 1
        except OSError:
            continue
    return removed


def clean_orphan_files(data_dir: Path, referenced: set[str], older_than_s: float = STALE_TEMP_S) -> int:
    """Delete stored files older than ``older_than_s`` that no row refers to.

    Such files are left by a crash between the file move and the commit, or between a delete's
    commit and the file removal.
    """
    removed = 0
    cutoff = time.time() - older_than_s
    for folder in ("maps", "images", "queries"):
        root = data_dir / folder
        if not root.is_dir():
            continue
        for path in root.rglob("*"):
            try:
                if (
                    path.is_file()
                    and str(path.relative_to(data_dir)) not in referenced
                    and path.stat().st_mtime < cutoff
                ):
                    path.unlink()
                    removed += 1
            except OSError:
                continue
    return removed
