"""The two settings that say where things live, read in one place.

- ``GEOLOC_SHARED``: the shared data and weights (read-only). Default: ``../shared`` from the
  repository root.
- ``GEOLOC_DATA_DIR``: the service's database, stored photos and caches (exported models).
  Default: ``~/.local/share/geoloc``.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def shared_dir() -> Path:
    """Folder with the shared data and weights (``GEOLOC_SHARED``)."""
    value = os.environ.get("GEOLOC_SHARED")
    return Path(value).expanduser().resolve() if value else (REPO_ROOT.parent / "shared").resolve()


def data_dir() -> Path:
    """Folder for the database, photos and caches (``GEOLOC_DATA_DIR``); created on demand."""
    value = os.environ.get("GEOLOC_DATA_DIR")
    path = Path(value).expanduser() if value else Path.home() / ".local" / "share" / "geoloc"
    path.mkdir(parents=True, exist_ok=True)
    return path.resolve()


def cache_dir() -> Path:
    """Folder for derived artefacts that can be rebuilt (exported ONNX models): ``DATA_DIR/cache``."""
    path = data_dir() / "cache"
    path.mkdir(parents=True, exist_ok=True)
    return path


def shared_path(*parts: str) -> Path:
    """A path inside the shared folder, with a clear error when it is missing."""
    path = shared_dir().joinpath(*parts)
    if not path.exists():
        raise FileNotFoundError(f"{path} not found; set GEOLOC_SHARED to the shared data folder (now {shared_dir()})")
    return path
