"""Where a map's shared SBoW base segment lives (:mod:`workers.sbow_share`): its folder, its name, its removal.

Apart from :mod:`workers.sbow_share` so that the API, which removes a deleted map's file, does not import the
index (numba and the method) to name it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path


def sbow_cache_dir(data_dir: Path) -> Path:
    """The folder of shared SBoW base segments under a data folder (``GEOLOC_DATA_DIR``): ``DATA_DIR/cache/sbow``."""
    return Path(data_dir) / "cache" / "sbow"


def shared_base_path(folder: Path, database: str, map_id: int, created_at: float) -> Path:
    """The file of one map's shared base segment (database key, map id and creation time in its name)."""
    key = hashlib.sha256(f"{database}\n{map_id}\n{created_at!r}".encode()).hexdigest()[:32]
    return Path(folder) / f"map{map_id}-{key}.sbow.npz"


def remove_shared_base(folder: Path, database: str, map_id: int, created_at: float) -> None:
    """Remove a deleted map's shared base file and its lock file (processes that map it keep their pages)."""
    path = shared_base_path(folder, database, map_id, created_at)
    path.unlink(missing_ok=True)
    path.with_name(path.name + ".lock").unlink(missing_ok=True)
