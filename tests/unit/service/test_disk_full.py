"""What counts as a full disk (``507``) and what stays an internal error, on real errors from the OS and SQLite."""

from __future__ import annotations

import errno
import sqlite3
from pathlib import Path

import psycopg
import pytest

from service.errors import is_disk_full


def _sqlite_full(tmp_path: Path) -> sqlite3.Error:
    """SQLite's own SQLITE_FULL: a database capped at its current size (``max_page_count``) takes a big row."""
    conn = sqlite3.connect(str(tmp_path / "capped.sqlite3"))
    conn.execute("CREATE TABLE t (x BLOB)")
    conn.execute("PRAGMA max_page_count = 3")
    try:
        conn.execute("INSERT INTO t VALUES (zeroblob(100000))")
    except sqlite3.Error as exc:
        return exc
    finally:
        conn.close()
    raise AssertionError("the capped database took the row")


def test_full_disk_errors(tmp_path: Path) -> None:
    assert is_disk_full(OSError(errno.ENOSPC, "No space left on device"))
    assert is_disk_full(OSError(errno.EDQUOT, "Disk quota exceeded"))
    full = _sqlite_full(tmp_path)
    assert is_disk_full(full)
    try:
        try:
            raise full
        except sqlite3.Error as inner:
            raise RuntimeError("storing failed") from inner
    except RuntimeError as outer:
        assert is_disk_full(outer), "the cause counts"


@pytest.mark.parametrize(
    "error",
    [OSError(errno.EACCES, "Permission denied"), sqlite3.OperationalError("no such table: t"), ValueError("x")],
)
def test_other_errors_are_not_a_full_disk(error: BaseException, tmp_path: Path) -> None:
    assert not is_disk_full(error, tmp_path)


def test_an_io_error_is_a_full_disk_only_when_the_disk_is_nearly_full(tmp_path: Path) -> None:
    io_error = sqlite3.OperationalError("disk I/O error")
    assert not is_disk_full(io_error, tmp_path), "this disk has room: a real I/O error, a 500"
    assert not is_disk_full(io_error), "without the data folder nothing can be told"


def test_postgres_disk_full_is_a_full_disk(tmp_path: Path) -> None:
    """PostgreSQL's SQLSTATE 53100 (``disk_full``, psycopg's ``DiskFull``) is a full disk.

    Other server errors are not.
    """
    assert is_disk_full(psycopg.errors.DiskFull("could not extend file: No space left on device"), tmp_path)
    assert not is_disk_full(psycopg.errors.UniqueViolation("duplicate key value"), tmp_path)
