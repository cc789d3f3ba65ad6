"""Fixtures shared by several test modules.

- every test starts and ends with freshly read settings (:func:`contracts.settings.reset_settings`), so a
  test or fixture that changes ``GEOLOC_*`` variables never leaks a cached value into the next one;
- ``built_models``: the models ``geoloc models build`` makes, built once into pytest's cache folder and
  reused while current (service data folders link to it with :func:`tests.model_fixtures.link_models`); the
  suite runs on three pytest-xdist workers (the README's ``-n 3``), so the build holds a file lock: one worker
  builds, the others wait and reuse it;
- ``profile``: the two deployment profiles, ``embedded`` (SQLite, built-in workers) and ``distributed``
  (PostgreSQL and Celery on Redis, real servers started once per session on loopback, see
  :mod:`testbed.servers`). A test or module fixture that takes it runs once per profile; each deployment it
  starts gets its own database from :meth:`Profile.new_env`.
"""

from __future__ import annotations

import fcntl
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from contracts.settings import reset_settings
from testbed.servers import PostgresServer, RedisServer

from .model_fixtures import data_dir_environment

PROFILES = ("embedded", "distributed")


@dataclass
class Profile:
    """A deployment profile for tests: ``embedded``, or ``distributed`` with its servers."""

    name: str
    postgres: PostgresServer | None = None
    redis: RedisServer | None = None

    @property
    def distributed(self) -> bool:
        """Whether this is the distributed profile."""
        return self.name == "distributed"

    def new_env(self) -> dict[str, str]:
        """Settings for one new deployment: nothing (embedded), or a fresh database and broker database.

        Pass the same dict to every process of that deployment (two API processes, a worker) so they share it.
        """
        if self.postgres is None or self.redis is None:
            return {}
        return {"GEOLOC_DATABASE_URL": self.postgres.new_database(), "GEOLOC_BROKER_URL": self.redis.new_url()}

    def new_deployment(self, data_dir: Path) -> tuple[Path | str, dict[str, str]]:
        """A fresh, migrated database for a deployment with data folder ``data_dir``, and its settings.

        Returns (SQLite file in ``data_dir``, ``{}``) or (PostgreSQL URL, :meth:`new_env`).
        """
        env = self.new_env()
        target: Path | str = env.get("GEOLOC_DATABASE_URL") or data_dir / "geoloc.sqlite3"
        from db import connect, migrate

        data_dir.mkdir(parents=True, exist_ok=True)
        db = connect(target)
        try:
            migrate(db)
        finally:
            db.close()
        return target, env


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[PostgresServer]:
    """A private PostgreSQL cluster on loopback for the session."""
    server = PostgresServer().start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture(scope="session")
def redis_server() -> Iterator[RedisServer]:
    """``redis-server`` on loopback for the session."""
    server = RedisServer().start()
    try:
        yield server
    finally:
        server.close()


@pytest.fixture(scope="session", params=PROFILES)
def profile(request: pytest.FixtureRequest) -> Profile:
    """Each deployment profile in turn (the distributed one starts the session's servers on first use)."""
    if request.param == "embedded":
        return Profile("embedded")
    return Profile("distributed", request.getfixturevalue("postgres_server"), request.getfixturevalue("redis_server"))


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
    later sessions while :func:`workers.context.model_problems` finds it complete and current.
    """
    cache = Path(request.config.cache.mkdir("geoloc-models"))
    with data_dir_environment(cache) as data_dir, (cache / "build.lock").open("w") as lock:
        from geoloc.export.models import build_segmentation_model
        from geoloc.export.vocabulary import build_default_vocabulary
        from geoloc.localize.retrieval import default_vocabulary
        from workers.context import method_context, model_problems

        fcntl.flock(lock, fcntl.LOCK_EX)  # xdist workers: the first builds, the others find it built
        if model_problems():
            build_segmentation_model()
            default_vocabulary.cache_clear()
            build_default_vocabulary(method_context(), progress=False)
    return data_dir / "cache" / "models"
