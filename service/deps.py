"""Shared request dependencies: the app's settings, a database connection, the file store, the job publisher."""

from __future__ import annotations

from collections.abc import Iterator

from fastapi import Request

from contracts.settings import Settings
from db import Database, connect
from db.files import FileStore
from workers.broker import JobPublisher


def app_settings(request: Request) -> Settings:
    """The app's settings: the one way the API reads them (a route dependency, or called with the request).

    They are the :class:`contracts.settings.Settings` given to :func:`service.app.create_app`, which a process
    entry point reads once with :func:`contracts.settings.get_settings` (tests pass their own); nothing in the
    API calls ``get_settings`` itself.
    """
    settings: Settings = request.app.state.settings
    return settings


def open_db(settings: Settings, lock_timeout_s: float | None = None) -> Database:
    """A connection for the API, bounded in time (past either bound the request is a ``503``).

    ``GEOLOC_DATABASE_TIMEOUT_S`` to connect (PostgreSQL), ``lock_timeout_s`` (default
    ``GEOLOC_DATABASE_LOCK_TIMEOUT_S``) for a lock.
    """
    lock_s = settings.database_lock_timeout_s if lock_timeout_s is None else lock_timeout_s
    return connect(settings.database, busy_timeout_ms=int(lock_s * 1000), connect_timeout_s=settings.database_timeout_s)


def get_db(request: Request) -> Iterator[Database]:
    """A database connection for one request (closed, or given back to the pool, afterwards)."""
    db = open_db(app_settings(request))
    try:
        yield db
    finally:
        db.close()


def get_store(request: Request) -> FileStore:
    """Where stored maps and photos live (``GEOLOC_STORE_DIR``, else ``GEOLOC_DATA_DIR``)."""
    store: FileStore = request.app.state.file_store
    return store


def get_publisher(request: Request) -> JobPublisher:
    """What hands committed jobs to the workers: nothing in the embedded profile, Celery in the distributed one."""
    publisher: JobPublisher = request.app.state.job_publisher
    return publisher
