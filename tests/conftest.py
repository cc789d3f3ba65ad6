"""Fixtures shared by several test modules.

- every test starts and ends with freshly read settings (:func:`geoloc.config.reset_settings`), so a
  test or fixture that changes ``GEOLOC_*`` variables never leaks a cached value into the next one;
- ``built_models``: the models ``geoloc models build`` makes, built once into pytest's cache folder and
  reused while current (service data folders link to it with :func:`tests.model_fixtures.link_models`).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from geoloc.config import reset_settings

from .model_fixtures import data_dir_environment


@pytest.fixture(autouse=True)
def fresh_settings() -> Iterator[None]:
    """Settings read from the environment as it is when the test starts (and again after it)."""
    reset_settings()
    yield
    reset_settings()


@pytest.fixture(scope="session")
def built_models(request: pytest.FixtureRequest) -> Path:
    """``DATA_DIR/cache/models`` with everything `geoloc models build` makes.

    Built into pytest's cache folder (``.pytest_cache/d/geoloc-models``, minutes on 2 cores) and reused by
    later sessions while :func:`geoloc.models.model_problems` finds it complete and current.
    """
    with data_dir_environment(Path(request.config.cache.mkdir("geoloc-models"))) as data_dir:
        from geoloc.models import build_segmentation_model, model_problems
        from geoloc.retrieval import default_vocabulary

        if model_problems():
            build_segmentation_model()
            default_vocabulary.cache_clear()
            default_vocabulary(progress=False)
            default_vocabulary.cache_clear()
    return data_dir / "cache" / "models"
