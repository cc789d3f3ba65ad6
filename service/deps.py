"""Shared request dependencies."""

from __future__ import annotations

from collections.abc import Iterator

import sqlite_utils
from fastapi import Request

from db import connect
from service.settings import Settings


def get_settings(request: Request) -> Settings:
    """The app's settings."""
    settings: Settings = request.app.state.settings
    return settings


def get_db(request: Request) -> Iterator[sqlite_utils.Database]:
    """A database connection for one request (closed afterwards)."""
    settings: Settings = request.app.state.settings
    db = connect(settings.database_path)
    try:
        yield db
    finally:
        db.close()
