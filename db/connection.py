"""Opening the database and running explicit transactions.

Connections are opened in autocommit mode (``isolation_level=None``): every write that must be
atomic goes through :func:`transaction`, which issues ``BEGIN IMMEDIATE`` so that the write lock
is taken up front (no deadlock-prone lock upgrades between worker processes).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import sqlite_utils

from geoloc.config import data_dir

DATABASE_FILENAME = "geoloc.sqlite3"
BUSY_TIMEOUT_MS = 30_000


def database_path() -> Path:
    """The service database file: ``GEOLOC_DATA_DIR/geoloc.sqlite3``."""
    return data_dir() / DATABASE_FILENAME


def connect(path: Path | str | None = None, *, busy_timeout_ms: int = BUSY_TIMEOUT_MS) -> sqlite_utils.Database:
    """Open (creating if needed) the database with WAL, a busy timeout and foreign keys on."""
    path = Path(path) if path is not None else database_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    conn = sqlite3.connect(str(path), timeout=busy_timeout_ms / 1000, isolation_level=None, check_same_thread=False)
    conn.execute(f"PRAGMA busy_timeout = {int(busy_timeout_ms)}")
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("PRAGMA synchronous = NORMAL")
    conn.execute("PRAGMA foreign_keys = ON")
    return sqlite_utils.Database(conn)


@contextmanager
def transaction(db: sqlite_utils.Database) -> Iterator[sqlite_utils.Database]:
    """``BEGIN IMMEDIATE`` ... ``COMMIT`` (``ROLLBACK`` on any exception). Not re-entrant.

    SQLite may already have rolled the transaction back itself (``SQLITE_FULL`` on a full disk, an I/O
    error); the rollback is then skipped so that the original error, not "no transaction is active",
    reaches the caller. A failed ``COMMIT`` is rolled back the same way.
    """
    db.execute("BEGIN IMMEDIATE")
    try:
        yield db
        db.execute("COMMIT")
    except BaseException:
        if db.conn.in_transaction:
            db.execute("ROLLBACK")
        raise
