"""Row counts, for health reports, the metrics (``GET /metrics``) and tests that check nothing was half-stored."""

from __future__ import annotations

from db.connection import Database

COUNTED_TABLES = (
    "maps",
    "buildings",
    "facades",
    "reference_images",
    "labels",
    "keypoints",
    "vocabularies",
    "sbow_documents",
    "sbow_postings",
    "jobs",
    "queries",
)


def table_counts(db: Database) -> dict[str, int]:
    """Number of rows per data table."""
    return {table: int(db.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0]) for table in COUNTED_TABLES}


def stored_file_paths(db: Database) -> set[str]:
    """Every file path (relative to the data dir) that a row refers to.

    Map sources, reference images and query images.
    """
    rows = db.execute(
        "SELECT source_path FROM maps UNION SELECT image_path FROM reference_images"
        " UNION SELECT image_path FROM queries WHERE image_path IS NOT NULL"
    ).fetchall()
    return {row[0] for row in rows}


def job_counts(db: Database) -> dict[tuple[str, str], int]:
    """Jobs by (kind, state): the table's statuses, with ``retrying`` for queued jobs already tried at least once."""
    rows = db.execute(
        "SELECT kind, CASE WHEN status = 'queued' AND attempts > 0 THEN 'retrying' ELSE status END AS state,"
        " COUNT(*) FROM jobs GROUP BY kind, state"
    ).fetchall()
    return {(str(kind), str(state)): int(count) for kind, state, count in rows}


def worker_heartbeats(db: Database) -> list[float]:
    """The last heartbeat (Unix s) of every worker process not marked stopped."""
    rows = db.execute("SELECT heartbeat_at FROM workers WHERE stopped_at IS NULL").fetchall()
    return [float(row[0]) for row in rows]


def catalogue_counts(db: Database) -> dict[str, dict[str, int]]:
    """Maps and references by status (``maps``, ``references``), and the SBoW index's documents (``index``)."""
    counts: dict[str, dict[str, int]] = {}
    for name, table in (("maps", "maps"), ("references", "reference_images")):
        rows = db.execute(f"SELECT status, COUNT(*) FROM {table} GROUP BY status").fetchall()
        counts[name] = {str(status): int(count) for status, count in rows}
    counts["index"] = {"documents": int(db.execute("SELECT COUNT(*) FROM sbow_documents").fetchone()[0])}
    return counts
