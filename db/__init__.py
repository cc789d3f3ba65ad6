"""SQLite storage for the service: connection setup, migrations and plain access functions.

Every function takes a ``sqlite_utils.Database`` (opened with :func:`db.connection.connect`).
No other package writes SQL: ``service/`` and ``workers/`` call these functions.
"""

from db.connection import connect, database_path, transaction
from db.migrations import LATEST_VERSION, migrate, schema_version

__all__ = ["LATEST_VERSION", "connect", "database_path", "migrate", "schema_version", "transaction"]
