"""Database outages told from other errors, on real SQLite files and a real PostgreSQL server."""

from __future__ import annotations

import socket
import sqlite3
import threading
from pathlib import Path

import psycopg
import pytest

from db import connect
from db.outages import (
    DatabaseUnavailableError,
    Reconnecting,
    is_connection_lost,
    is_database_unavailable,
    outage_reason,
    until_available,
)
from testbed.servers import PostgresServer


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_sqlite_locked_is_unavailable_but_not_a_lost_connection(tmp_path: Path) -> None:
    path = tmp_path / "geoloc.sqlite3"
    holder = connect(path)
    holder.execute("CREATE TABLE t (x INTEGER)")
    holder.execute("BEGIN IMMEDIATE")
    other = connect(path, busy_timeout_ms=50)
    with pytest.raises(sqlite3.OperationalError) as caught:
        other.execute("INSERT INTO t VALUES (1)")
    holder.execute("ROLLBACK")
    assert is_database_unavailable(caught.value)
    assert not is_connection_lost(caught.value), "a busy timeout counts as an attempt"


def test_sqlite_read_only_is_unavailable_and_lost(tmp_path: Path) -> None:
    path = tmp_path / "geoloc.sqlite3"
    connect(path).execute("CREATE TABLE t (x INTEGER)")
    read_only = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    with pytest.raises(sqlite3.OperationalError) as caught:
        read_only.execute("INSERT INTO t VALUES (1)")
    assert is_database_unavailable(caught.value) and is_connection_lost(caught.value)


def test_other_errors_are_not_outages(tmp_path: Path) -> None:
    db = connect(tmp_path / "geoloc.sqlite3")
    with pytest.raises(sqlite3.OperationalError) as caught:
        db.execute("SELECT * FROM no_such_table")
    assert not is_database_unavailable(caught.value)
    assert not is_database_unavailable(ValueError("database is locked"))


def test_postgres_refused_is_unavailable_and_bounded() -> None:
    url = f"postgresql://geoloc@127.0.0.1:{_closed_port()}/nothing"
    with pytest.raises(psycopg.OperationalError) as caught:
        connect(url, connect_timeout_s=2)
    assert is_database_unavailable(caught.value) and is_connection_lost(caught.value)
    assert "/" not in outage_reason(RuntimeError("cannot open /var/lib/secret/geoloc.sqlite3"))


def test_pool_drops_a_connection_the_server_ended(postgres_server: PostgresServer) -> None:
    url = postgres_server.new_database()
    db = connect(url)
    pid = db.execute("SELECT pg_backend_pid()").fetchone()[0]
    db.close()  # back to the pool, idle
    with psycopg.connect(url, autocommit=True) as killer:  # not from the pool: that would be the same connection
        killer.execute("SELECT pg_terminate_backend(%s)", (pid,)).fetchone()
    threading.Event().wait(0.2)  # the server's goodbye reaches the idle socket
    again = connect(url)
    try:
        assert again.execute("SELECT pg_backend_pid()").fetchone()[0] != pid, "a fresh connection, not the dead one"
    finally:
        again.close()


def test_reconnecting_opens_again_after_a_failure(tmp_path: Path) -> None:
    path = tmp_path / "geoloc.sqlite3"
    link = Reconnecting(path)
    first = link.get()
    calls = {"n": 0}

    def flaky(db: object) -> int:
        calls["n"] += 1
        if calls["n"] == 1:
            raise sqlite3.OperationalError("database is locked")
        return 7

    with pytest.raises(sqlite3.OperationalError):
        link.attempt(flaky)
    assert link.attempt(flaky) == 7 and link.get() is not first
    link.close()


def test_until_available_waits_then_gives_up_on_stop() -> None:
    stop = threading.Event()
    tries = {"n": 0}

    def twice_locked() -> str:
        tries["n"] += 1
        if tries["n"] < 3:
            raise sqlite3.OperationalError("database is locked")
        return "ok"

    assert until_available(twice_locked, stop, "test") == "ok"
    stop.set()
    with pytest.raises(DatabaseUnavailableError):
        until_available(lambda: (_ for _ in ()).throw(sqlite3.OperationalError("database is locked")), stop, "test")
    with pytest.raises(ValueError, match="not an outage"):
        until_available(lambda: (_ for _ in ()).throw(ValueError("not an outage")), stop, "test")
