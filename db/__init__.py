"""Storage for the service: SQLite (embedded) or PostgreSQL (distributed), migrations and plain access functions.

Every function takes a :class:`db.connection.Database` (opened with :func:`db.connection.connect`).
No other package writes SQL: ``service/`` and ``workers/`` call these functions.
"""

from db.connection import Database, connect, database_path, is_postgres_url, transaction
from db.migrations import LATEST_VERSION, migrate, schema_version

__all__ = [
    "LATEST_VERSION",
    "Database",
    "connect",
    "database_path",
    "is_postgres_url",
    "migrate",
    "schema_version",
    "transaction",
]
