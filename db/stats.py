"""Row counts, for health reports and for tests that check nothing was half-stored."""

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
