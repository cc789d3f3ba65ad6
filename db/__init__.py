"""Storage for the service: SQLite (embedded) or PostgreSQL (distributed), migrations and plain access functions.

Every function takes a :class:`db.connection.Database` (opened with :func:`db.connection.connect`).
No other package writes SQL: ``service/`` and ``workers/`` call these functions. ``db`` imports only
``contracts`` (and third-party packages).

Rows come back typed: ``TypedDict``s in :mod:`db.rows` (``MapRow``, ``ReferenceRow``, ``QueryRow``, ``JobRow``,
``WorkerRow``), plain dicts that mypy checks key by key (decision: no dataclasses, so the rows stay the JSON-like
dicts the job API and the tests read). Stored structures have their contracts: job payloads
(:mod:`contracts.jobs`), query parameters (:mod:`contracts.queries`), a reference's keypoint and label arrays
(:mod:`contracts.references`).
"""

from db.connection import Database, connect, database_key, database_path, is_postgres_url, transaction
from db.migrations import LATEST_VERSION, migrate, schema_version

__all__ = [
    "LATEST_VERSION",
    "Database",
    "connect",
    "database_key",
    "database_path",
    "is_postgres_url",
    "migrate",
    "schema_version",
    "transaction",
]
