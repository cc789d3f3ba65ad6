"""A session-wide cache of built models (ONNX segmentation network, SBoW vocabulary) for tests that run
the real method in a service; each service data folder links its ``cache/models`` to it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def built_models(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``DATA_DIR/cache/models`` with everything `geoloc models build` makes (built once per session).

    Each test module that imports this fixture gets its own session-scoped instance, so the build
    lives at a fixed place in the session's temporary folder and later instances reuse it.
    """
    data_dir = tmp_path_factory.getbasetemp() / "models-data"
    built_marker = data_dir / "built"
    if built_marker.exists():
        return data_dir / "cache" / "models"
    data_dir.mkdir(exist_ok=True)
    previous = os.environ.get("GEOLOC_DATA_DIR")
    os.environ["GEOLOC_DATA_DIR"] = str(data_dir)
    try:
        from geoloc.models import build_segmentation_model
        from geoloc.retrieval import default_vocabulary

        build_segmentation_model()
        default_vocabulary.cache_clear()
        default_vocabulary(progress=False)
        default_vocabulary.cache_clear()
    finally:
        if previous is None:
            os.environ.pop("GEOLOC_DATA_DIR", None)
        else:
            os.environ["GEOLOC_DATA_DIR"] = previous
    built_marker.touch()
    return data_dir / "cache" / "models"


def link_models(data_dir: Path, models: Path) -> None:
    """Make a service data folder use the built models."""
    (data_dir / "cache").mkdir(parents=True, exist_ok=True)
    target = data_dir / "cache" / "models"
    if not target.exists():
        target.symlink_to(models, target_is_directory=True)
