"""Which database errors mean "unavailable for now" (a 503 and a retry), and waiting for the database to return.

PostgreSQL stopped, restarting or unreachable raises :class:`psycopg.OperationalError` (refused or timed-out
connections, ``admin_shutdown``, ``cannot_connect_now``, ``lock_not_available`` past ``lock_timeout``) or
:class:`psycopg.InterfaceError` (a pooled connection the server closed); an embedded SQLite file that cannot be
written or opened for now raises :class:`sqlite3.OperationalError` with ``SQLITE_BUSY``/``SQLITE_LOCKED`` (the
busy timeout ran out), ``SQLITE_READONLY`` (a read-only volume), ``SQLITE_CANTOPEN`` or ``SQLITE_IOERR`` (the
volume gone). A full disk is not an outage: the API answers it with ``507`` (``service/errors.py``), so callers
check that first.
"""

from __future__ import annotations

import logging
import sqlite3
import threading
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import TypeVar

import psycopg

from db.connection import Database, connect

log = logging.getLogger("geoloc.db")

T = TypeVar("T")

SQLITE_UNAVAILABLE = frozenset(
    {sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED, sqlite3.SQLITE_READONLY, sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_IOERR}
)
"""Primary SQLite result codes that mean the file cannot be used for now."""
LOST_SQLITE = frozenset({sqlite3.SQLITE_READONLY, sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_IOERR})
SQLITE_UNAVAILABLE_TEXT = ("locked", "busy", "readonly", "read-only", "unable to open", "disk I/O error")
RETRY_MIN_S = 0.2
RETRY_MAX_S = 5.0
"""Backoff between tries while the database is away: from this much, doubled, up to :data:`RETRY_MAX_S`."""


class DatabaseUnavailableError(Exception):
    """Waiting for the database ended (a stop was requested) before it came back."""


def is_database_unavailable(exc: BaseException) -> bool:
    """Whether ``exc`` (or an exception it was raised from) means the database is away for now."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, psycopg.OperationalError | psycopg.InterfaceError) and not isinstance(
            current, psycopg.errors.DiskFull
        ):
            return True
        if isinstance(current, sqlite3.OperationalError):
            code = getattr(current, "sqlite_errorcode", None)
            if code is not None and code & 0xFF in SQLITE_UNAVAILABLE:
                return True
            if code is None and any(text in str(current) for text in SQLITE_UNAVAILABLE_TEXT):
                return True
        current = current.__cause__ or current.__context__
    return False


def is_connection_lost(exc: BaseException) -> bool:
    """Whether ``exc`` (or its cause) means the connection itself was lost, not a statement refused.

    PostgreSQL: a client-side error without SQLSTATE (refused, reset, closed), a connection exception (class
    ``08``) or the server shutting down or starting (``57P01``-``57P03``); a lock or statement timeout is not.
    SQLite: the file cannot be opened, read or written (``SQLITE_CANTOPEN``, ``SQLITE_IOERR``, ``SQLITE_READONLY``);
    a busy timeout is not. A job whose attempt failed this way did not fail on its own: it is given back uncounted.
    """
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, psycopg.InterfaceError):
            return True
        if isinstance(current, psycopg.OperationalError):
            state = current.sqlstate
            return state is None or state.startswith("08") or state in ("57P01", "57P02", "57P03")
        if isinstance(current, sqlite3.OperationalError):
            code = getattr(current, "sqlite_errorcode", None)
            return code is not None and code & 0xFF in LOST_SQLITE
        current = current.__cause__ or current.__context__
    return False


def outage_reason(exc: BaseException) -> str:
    """A short reason for a log line or ``/readyz``: the error's type and first line, without file paths."""
    first = (str(exc).strip().splitlines() or [""])[0]
    if "/" in first:  # a path (a socket, a file) says nothing the operator's logs do not
        first = " ".join(word for word in first.split() if "/" not in word)
    return f"{type(exc).__name__}: {first}"[:200]


class Reconnecting:
    """A database connection opened again after an outage: :meth:`attempt` drops a connection that failed.

    ``borrowed`` (a caller's connection) is used first and never closed here; connections opened here are
    closed by :meth:`close`.
    """

    def __init__(self, target: Path | str, borrowed: Database | None = None) -> None:
        self.target = target
        self._db = borrowed
        self._own = borrowed is None

    def get(self) -> Database:
        """The current connection, opened if there is none."""
        if self._db is None:
            self._db, self._own = connect(self.target), True
        return self._db

    def attempt(self, call: Callable[[Database], T]) -> T:
        """``call(connection)``; a failure that means the database is away drops the connection and is raised."""
        try:
            return call(self.get())
        except Exception as exc:
            if is_database_unavailable(exc):
                self.drop()
            raise

    def drop(self) -> None:
        """Forget the current connection (closed when it was opened here)."""
        db, self._db = self._db, None
        if db is not None and self._own:
            with suppress(Exception):
                db.close()

    close = drop


def until_available(call: Callable[[], T], stop: threading.Event, what: str) -> T:
    """``call()``, tried again while it fails because the database is away, until it succeeds or ``stop`` is set.

    Raises
    ------
    DatabaseUnavailableError
        ``stop`` was set while the database was still away.
    """
    delay = RETRY_MIN_S
    warned = False
    while True:
        try:
            result = call()
        except Exception as exc:
            if not is_database_unavailable(exc):
                raise
            if not warned:
                log.warning("%s: the database is unavailable (%s); retrying", what, outage_reason(exc))
                warned = True
            if stop.wait(delay):
                raise DatabaseUnavailableError(f"{what}: stopped while the database was unavailable") from exc
            delay = min(delay * 2, RETRY_MAX_S)
            continue
        if warned:
            log.info("%s: the database is back", what)
        return result


def retry_pause_s(failures: int) -> float:
    """Seconds to wait after ``failures`` failed tries in a row: :data:`RETRY_MIN_S` doubled, at most 5 s."""
    return float(min(RETRY_MIN_S * 2 ** max(failures - 1, 0), RETRY_MAX_S))
