"""The file store: uploaded maps and photos, by key, where every API process and worker can reach them.

A key is a relative path such as ``images/<map_id>/<sha256>.jpg``; the database rows hold keys, never
absolute paths. The one implementation is :class:`DirectoryStore`, a folder (``GEOLOC_STORE_DIR``,
else ``GEOLOC_DATA_DIR``): on one machine a local folder, in the distributed profile a volume every
node mounts (NFS, a Docker volume, a cloud file share). :class:`FileStore` is all the service needs,
so an object store can follow: ``put`` uploads, ``local_path`` downloads into a local cache.

Uploads are first received into :meth:`FileStore.temp_dir` (on the store's file system, so that
:meth:`FileStore.put` is a rename) and put under their key inside the database transaction that
records them.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

STORED_FOLDERS = ("maps", "images", "queries")
"""Top-level key prefixes of stored files (``tmp/`` holds uploads being received)."""


class FileStore(Protocol):
    """Where stored files live, by key."""

    def local_path(self, key: str) -> Path:
        """A local file with the stored bytes of ``key`` (it may not exist)."""

    def temp_dir(self) -> Path:
        """A local folder for uploads being received (created on demand)."""

    def put(self, source: Path, key: str) -> bool:
        """Move the local file ``source`` to ``key``; True if that created the key (False: it existed)."""

    def delete(self, *keys: str) -> None:
        """Remove these keys, ignoring ones already gone."""

    def remove_empty_folders(self, *keys: str) -> None:
        """Remove these key prefixes if nothing is stored under them (nothing to do in a store without folders)."""

    def stored_keys(self, older_than_s: float) -> Iterator[str]:
        """Every stored key last written more than ``older_than_s`` seconds ago."""


class DirectoryStore:
    """A :class:`FileStore` in a folder: the key is the path below ``root``."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def local_path(self, key: str) -> Path:
        """``root / key``."""
        return self.root / key

    def temp_dir(self) -> Path:
        """``root/tmp`` (same file system as the stored files, so :meth:`put` is a rename)."""
        path = self.root / "tmp"
        path.mkdir(parents=True, exist_ok=True)
        return path

    def put(self, source: Path, key: str) -> bool:
        """Rename ``source`` to ``root / key`` (creating folders); True if the file was not there before."""
        final_path = self.root / key
        final_path.parent.mkdir(parents=True, exist_ok=True)
        existed = final_path.exists()
        os.replace(source, final_path)
        return not existed

    def delete(self, *keys: str) -> None:
        """Unlink ``root / key`` for each key, ignoring ones already gone."""
        for key in keys:
            with contextlib.suppress(OSError):
                (self.root / key).unlink(missing_ok=True)

    def remove_empty_folders(self, *keys: str) -> None:
        """Remove these folders (keys of folders) if they are empty."""
        for key in keys:
            with contextlib.suppress(OSError):
                (self.root / key).rmdir()

    def stored_keys(self, older_than_s: float) -> Iterator[str]:
        """Files under :data:`STORED_FOLDERS` whose modification time is older than ``older_than_s``."""
        cutoff = time.time() - older_than_s
        for folder in STORED_FOLDERS:
            base = self.root / folder
            if not base.is_dir():
                continue
            for path in base.rglob("*"):
                with contextlib.suppress(OSError):
                    if path.is_file() and path.stat().st_mtime < cutoff:
                        yield str(path.relative_to(self.root))


def open_store(root: Path) -> DirectoryStore:
    """The file store at ``root`` (``Settings.file_store_dir``)."""
    return DirectoryStore(root)
