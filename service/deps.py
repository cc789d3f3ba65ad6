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


def get_db(request: Request) -> Iterator[Database]:
    """A database connection for one request (closed, or given back to the pool, afterwards)."""
    db = connect(app_settings(request).database)
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
