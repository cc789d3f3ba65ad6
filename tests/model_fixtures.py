"""Helpers for tests that point ``GEOLOC_DATA_DIR`` at a temporary folder (the fixtures are in ``conftest.py``)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from contracts.settings import reset_settings


@contextmanager
def data_dir_environment(data_dir: Path) -> Iterator[Path]:
    """Set ``GEOLOC_DATA_DIR`` to ``data_dir`` in this process, restore it on exit; settings re-read both times."""
    previous = os.environ.get("GEOLOC_DATA_DIR")
    os.environ["GEOLOC_DATA_DIR"] = str(data_dir)
    reset_settings()
    try:
        yield data_dir
    finally:
        if previous is None:
            os.environ.pop("GEOLOC_DATA_DIR", None)
        else:
            os.environ["GEOLOC_DATA_DIR"] = previous
        reset_settings()


def link_models(data_dir: Path, models: Path) -> None:
    """Make a service data folder use the built models."""
    (data_dir / "cache").mkdir(parents=True, exist_ok=True)
    target = data_dir / "cache" / "models"
    if not target.exists():
        target.symlink_to(models, target_is_directory=True)
