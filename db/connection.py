"""Opening the database (SQLite or PostgreSQL) and running explicit transactions.

One :class:`Database` class serves both engines, so the access modules hold one set of plain SQL:

- statements use ``?`` placeholders (translated to ``%s`` for PostgreSQL) and the SQL both engines
  share (``INSERT ... ON CONFLICT``, ``RETURNING``, ``CASE``); the few places where they differ ask
  :class:`Database` for the fragment (:attr:`Database.skip_locked`, :meth:`Database.lock`);
- connections are in autocommit mode: every write that must be atomic goes through
  :func:`transaction`. On SQLite it issues ``BEGIN IMMEDIATE`` (the write lock is taken up front,
  so writers are serialised and no lock upgrade can deadlock between worker processes). On
  PostgreSQL it is a plain ``BEGIN`` (READ COMMITTED); the checks that SQLite's single writer made
  race-free (a duplicate upload, the queue limit) take a transaction-scoped advisory lock with
  :meth:`Database.lock`, and claims use ``FOR UPDATE SKIP LOCKED``.

:func:`connect` picks the engine from its target: a ``postgresql://`` URL (``GEOLOC_DATABASE_URL``)
or a file path (the embedded default, ``GEOLOC_DATA_DIR/geoloc.sqlite3``). PostgreSQL connections are
pooled per process (:meth:`Database.close` hands an idle one back), since opening one costs a server
process fork.
"""

from __future__ import annotations

import os
import re
import select
import sqlite3
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal, Protocol

from contracts.settings import data_dir

DATABASE_FILENAME = "geoloc.sqlite3"
BUSY_TIMEOUT_MS = 30_000
CONNECT_TIMEOUT_S = 10.0
"""PostgreSQL's connect timeout unless the caller gives one (the API passes ``GEOLOC_DATABASE_TIMEOUT_S``)."""
POSTGRES_SCHEMES = ("postgresql://", "postgres://", "postgresql+psycopg://")
POOL_IDLE_MAX = 8
"""Idle PostgreSQL connections kept per process and URL."""

Dialect = Literal["sqlite", "postgresql"]
Params = Sequence[Any] | None


class Cursor(Protocol):
    """The part of a DB-API cursor the access modules use."""

    @property
    def rowcount(self) -> int:
        """Rows changed by the statement."""

    @property
    def description(self) -> Any:
        """Column descriptions of the result (``[0]`` of each is the name)."""

    def fetchone(self) -> Any:
        """The next row (a tuple), or None."""

    def fetchall(self) -> list[Any]:
        """The remaining rows (tuples)."""

    def fetchmany(self, size: int) -> list[Any]:
        """Up to ``size`` of the remaining rows (tuples)."""


def database_path() -> Path:
    """The embedded database file: ``GEOLOC_DATA_DIR/geoloc.sqlite3``."""
    return data_dir() / DATABASE_FILENAME


def is_postgres_url(target: object) -> bool:
    """Whether ``target`` is a PostgreSQL URL (else it is a SQLite file path)."""
    return isinstance(target, str) and target.startswith(POSTGRES_SCHEMES)


def _qmark_to_format(sql: str) -> str:
    """``?`` placeholders to psycopg's ``%s`` (a literal ``%`` becomes ``%%``); no SQL here has ``?`` in a string."""
    return sql.replace("%", "%%").replace("?", "%s")


class Database:
    """One connection to the service database, SQLite or PostgreSQL, with ``?`` placeholders.

    Parameters
    ----------
    conn
        A ``sqlite3.Connection`` (autocommit) or a ``psycopg.Connection`` (autocommit).
    dialect
        ``"sqlite"`` or ``"postgresql"``.
    release
        Called with the raw connection by :meth:`close` (the PostgreSQL pool); None closes it.
    """

    def __init__(self, conn: Any, dialect: Dialect, release: Any = None) -> None:
        self.conn = conn
        self.dialect: Dialect = dialect
        self._release = release
        self._translated: dict[str, str] = {}

    @property
    def is_postgres(self) -> bool:
        """Whether this is a PostgreSQL connection."""
        return self.dialect == "postgresql"

    @property
    def skip_locked(self) -> str:
        """``FOR UPDATE SKIP LOCKED`` on PostgreSQL (for a claim's sub-select), empty on SQLite."""
        return " FOR UPDATE SKIP LOCKED" if self.is_postgres else ""

    def _sql(self, sql: str) -> str:
        if not self.is_postgres:
            return sql
        translated = self._translated.get(sql)
        if translated is None:
            translated = self._translated[sql] = _qmark_to_format(sql)
        return translated

    def execute(self, sql: str, params: Params = None) -> Cursor:
        """Run one statement; returns its cursor (``fetchone``, ``fetchall``, ``rowcount``)."""
        if self.is_postgres:
            cursor = self.conn.cursor()
            cursor.execute(self._sql(sql), tuple(params) if params is not None else ())
            return cursor  # type: ignore[no-any-return]
        return self.conn.execute(sql, tuple(params) if params is not None else ())  # type: ignore[no-any-return]

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        """Run one statement once per row of parameters."""
        if not rows:
            return
        if self.is_postgres:
            with self.conn.cursor() as cursor:
                cursor.executemany(self._sql(sql), rows)
        else:
            self.conn.executemany(sql, rows)

    def query(self, sql: str, params: Params = None) -> Iterator[dict[str, Any]]:
        """The rows of a ``SELECT`` as dicts (column name -> value)."""
        cursor = self.execute(sql, params)
        columns = [d[0] for d in cursor.description]
        for row in cursor.fetchall():
            yield dict(zip(columns, row, strict=True))

    def insert_returning_id(self, sql: str, params: Params) -> int:
        """Run an ``INSERT`` and return the new row's ``id`` (the statement gets ``RETURNING id``)."""
        row = self.execute(f"{sql} RETURNING id", params).fetchone()
        return int(row[0])

    @property
    def in_transaction(self) -> bool:
        """Whether a transaction is open on this connection."""
        if self.is_postgres:
            from psycopg.pq import TransactionStatus

            return bool(self.conn.info.transaction_status != TransactionStatus.IDLE)
        return bool(self.conn.in_transaction)

    def lock(self, key: str) -> None:
        """Hold a lock named ``key`` until the current transaction ends.

        PostgreSQL: ``pg_advisory_xact_lock`` on a hash of the name, so that transactions checking the
        same thing (one photo's duplicate, the queue's depth) run one after the other. SQLite: nothing
        to do, ``BEGIN IMMEDIATE`` already made this transaction the only writer.
        """
        if self.is_postgres:
            self.execute("SELECT pg_advisory_xact_lock(hashtextextended(?, 0))", (key,)).fetchone()

    def close(self) -> None:
        """Close the connection (a PostgreSQL one goes back to its pool when it is idle and healthy)."""
        conn, self.conn = self.conn, None
        if conn is None:
            return
        if self._release is not None:
            self._release(conn)
        else:
            conn.close()


def database_key(db: Database) -> str:
    """Which database this is (several may live in one process, e.g. in tests): its file or server and name."""
    if db.is_postgres:
        info = db.conn.info
        return f"postgresql://{info.host}:{info.port}/{info.dbname}"
    rows = db.execute("PRAGMA database_list").fetchall()
    return str(next((row[2] for row in rows if row[1] == "main"), ""))


def connect(
    target: Path | str | None = None,
    *,
    busy_timeout_ms: int = BUSY_TIMEOUT_MS,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
) -> Database:
    """Open the database at ``target``: a PostgreSQL URL, or a SQLite file (created if needed).

    SQLite is opened with WAL, a busy timeout and foreign keys on; PostgreSQL in autocommit, from a
    per-process pool, with ``busy_timeout_ms`` as its ``lock_timeout`` and ``connect_timeout_s`` (whole
    seconds, at least 2: libpq's rule) bounding a new connection; TCP keepalives and ``tcp_user_timeout``
    bound a query on a connection whose server vanished without closing it.
    """
    if is_postgres_url(target):
        return _pool_for(str(target)).get(busy_timeout_ms, connect_timeout_s)
    path = Path(target) if target is not None else database_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    conn = sqlite3.connect(str(path), timeout=busy_timeout_ms / 1000, isolation_level=None, check_same_thread=False)
    conn.execute(f"PRAGMA busy_timeout = {int(busy_timeout_ms)}")
    _set_wal(conn, busy_timeout_ms)
    conn.execute("PRAGMA synchronous = NORMAL")
    conn.execute("PRAGMA foreign_keys = ON")
    return Database(conn, "sqlite")


def _set_wal(conn: sqlite3.Connection, busy_timeout_ms: int) -> None:
    """Switch to WAL, retrying while another connection holds the lock, up to the busy timeout.

    On a new database file, connections made at once (the API and the workers starting together) race to
    switch it, and SQLite answers the loser "database is locked" at once, without its busy handler.
    """
    deadline = time.monotonic() + busy_timeout_ms / 1000
    while True:
        try:
            conn.execute("PRAGMA journal_mode = WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() >= deadline:
                raise
            time.sleep(0.01)


def _closed_by_server(conn: Any) -> bool:
    """Whether an idle pooled connection was closed by its server (it has something to read: an error, EOF).

    A server that stopped or restarted ends its idle sessions; without this check the first request after it
    comes back would get one of those dead connections.
    """
    try:
        readable, _, _ = select.select([conn.fileno()], [], [], 0)
    except (OSError, ValueError):
        return True
    return bool(readable)


class _PostgresPool:
    """Idle PostgreSQL connections of one URL in this process (forgotten after a fork), with their lock timeouts."""

    def __init__(self, url: str) -> None:
        self.url = re.sub(r"^postgresql\+psycopg://", "postgresql://", url)
        self.pid = os.getpid()
        self.idle: list[Any] = []
        self.lock_timeouts: dict[int, int] = {}
        """``lock_timeout`` (ms) of each idle connection, by ``id``."""
        self.lock = threading.Lock()

    def get(self, busy_timeout_ms: int, connect_timeout_s: float = CONNECT_TIMEOUT_S) -> Database:
        import psycopg

        conn, lock_timeout, had = None, int(busy_timeout_ms), None
        with self.lock:
            if self.pid != os.getpid():  # inherited through fork: the server talks to the parent on these
                self.idle, self.lock_timeouts, self.pid = [], {}, os.getpid()
            while self.idle and conn is None:
                candidate = self.idle.pop()
                had = self.lock_timeouts.pop(id(candidate), None)
                if candidate.closed or _closed_by_server(candidate):
                    candidate.close()
                    continue
                conn = candidate
        if conn is not None and had != lock_timeout:
            conn.execute(f"SET lock_timeout = {lock_timeout}")
        if conn is None:
            timeout_ms = int(max(connect_timeout_s, 2.0) * 1000)
            conn = psycopg.connect(
                self.url,
                autocommit=True,
                connect_timeout=max(int(round(connect_timeout_s)), 2),
                options=f"-c lock_timeout={lock_timeout}",
                keepalives=1,
                keepalives_idle=max(timeout_ms // 1000, 1),
                keepalives_interval=1,
                keepalives_count=3,
                tcp_user_timeout=timeout_ms,
            )
        return Database(conn, "postgresql", release=lambda raw: self.release(raw, lock_timeout))

    def release(self, conn: Any, lock_timeout: int | None = None) -> None:
        from psycopg.pq import TransactionStatus

        healthy = not conn.closed and not conn.broken and conn.info.transaction_status == TransactionStatus.IDLE
        with self.lock:
            if healthy and self.pid == os.getpid() and len(self.idle) < POOL_IDLE_MAX:
                self.idle.append(conn)
                if lock_timeout is not None:
                    self.lock_timeouts[id(conn)] = lock_timeout
                return
        conn.close()


_pools: dict[str, _PostgresPool] = {}
_pools_lock = threading.Lock()


def _pool_for(url: str) -> _PostgresPool:
    with _pools_lock:
        pool = _pools.get(url)
        if pool is None:
            pool = _pools[url] = _PostgresPool(url)
        return pool


@contextmanager
def transaction(db: Database) -> Iterator[Database]:
    """``BEGIN IMMEDIATE`` (SQLite) or ``BEGIN`` (PostgreSQL) ... ``COMMIT``; ``ROLLBACK`` on any exception.

    Not re-entrant. SQLite may already have rolled the transaction back itself (``SQLITE_FULL`` on a full
    disk, an I/O error); the rollback is then skipped so that the original error, not "no transaction is
    active", reaches the caller. A failed ``COMMIT`` is rolled back the same way.
    """
    db.execute("BEGIN" if db.is_postgres else "BEGIN IMMEDIATE")
    try:
        yield db
        db.execute("COMMIT")
    except BaseException:
        if db.conn is not None and not getattr(db.conn, "closed", False) and db.in_transaction:
            db.execute("ROLLBACK")
        raise
