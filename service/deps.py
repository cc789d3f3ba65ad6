"""Shared request dependencies: settings, a database connection, the file store, the job publisher."""

from __future__ import annotations

from collections.abc import Iterator

from fastapi import Request

from db import Database, connect
from db.files import FileStore
from service.settings import Settings
from workers.broker import JobPublisher


def get_settings(request: Request) -> Settings:
    """The app's settings."""
    settings: Settings = request.app.state.settings
    return settings


def get_db(request: Request) -> Iterator[Database]:
    """A database connection for one request (closed, or given back to the pool, afterwards)."""
    settings: Settings = request.app.state.settings
    db = connect(settings.database)
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
