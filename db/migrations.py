"""Numbered schema migrations, applied in order at start (idempotent), one set for SQLite and PostgreSQL.

The DDL is written once, in SQLite's words; :func:`portable_ddl` renders it for PostgreSQL (64-bit
identity keys, ``DOUBLE PRECISION`` for ``REAL``, ``BYTEA`` for ``BLOB``, no ``WITHOUT ROWID``), so
both engines get the same tables, columns, keys, constraints and indexes. The applied version is the
highest in ``schema_migrations`` (SQLite also keeps it in ``PRAGMA user_version``, as before). A
migration is applied inside one transaction together with its ``schema_migrations`` row, under the
write lock (SQLite) or an advisory lock (PostgreSQL), so concurrent starters (API processes and
workers) cannot apply the same migration twice.

Storage decisions (see also the module docstrings of the access modules):

- ``reference_images`` is the table for references (``references`` is an SQL keyword).
- Facades are stored as one ``.npz`` blob per map (``facades``, uncompressed: floats hardly compress),
  not as rows: the method always needs all facades of a map at once, as arrays.
- Labels, keypoints and the vocabulary are blobs (``.npz``); the inverted index is a real table
  ``sbow_postings(map_id, word_id, reference_id, weight)`` whose rows cascade from the
  reference, so adding or deleting a reference keeps the index consistent in one transaction.
- Times are Unix seconds (REAL, UTC; double precision in both engines).
- ``maps.read_options`` (migration 2) holds how the map file was read (GIS layer, attribute names,
  CRS; ``{}`` for the defaults): one file read with other options is another map.
- ``sbow_changes`` (migration 3) logs every change of a map's inverted index (a reference indexed,
  re-indexed or deleted) with an increasing ``seq``: the workers' in-memory copies of the index
  (``workers/reference_store.py``) catch up by reading the log past their high-water mark. Existing
  documents are logged once when the migration runs.
- ``jobs.published_at`` (migration 4) is when the job's id was last handed to the broker (distributed
  profile; see :mod:`workers.broker`); the embedded pool claims from the table and never sets it.
- ``reference_images.prior_heading_accuracy_deg`` (migration 5) is the accuracy (deg) of a heading prior
  that came from the photo's compass; NULL for a heading the uploader stated (and for every reference
  stored before it), which the worker weights as before (:mod:`workers.handler_helpers`).
- ``maps.attribution`` (migration 6) is the attribution the map upload stated (its data's licence requires it
  shown with everything derived from the map); NULL when the upload stated none, and for every map stored
  before it: the API then shows the default, "© OpenStreetMap contributors" (:mod:`contracts.licenses`).
- ``reference_images.sequence_id``, ``capture_time``, ``device`` and ``placement`` (migration 7): the walk a
  reference belongs to (the upload's ``sequence`` field, else the photo's Mapillary sequence id; NULL: none
  stated), when it was taken (ISO 8601 as the photo states it: aware, or naive camera time), its camera (EXIF
  make and model), and whether its pose is its own label's (``alone``, every reference stored before) or its
  sequence's joint placement (``sequence``; :mod:`geoloc.localize.sequence`).
- ``maps.tenant`` (migration 8): the tenant of the API key that uploaded the map (NULL: untenanted, every map
  stored before it). References and queries have no tenant of their own: they belong to their map's
  (``service/tenancy.py``); every query and reference has a map (``map_id NOT NULL``). ``jobs.tenant``
  (migration 8) is stamped when the job is queued (the tenant given, else its map's), so a job keeps its
  tenant without a map (one queued before its map exists, or after its map is deleted).
- ``maps.status``, ``error`` (with ``error_code`` and ``error_details``, JSON: the reader's machine reason and
  facts), ``job_id``, ``parsed_elements``, ``parsed_buildings`` (migration 9): a map is parsed
  by a ``load_map`` job (:mod:`workers.map_handlers`); until it is ``done`` its row holds no buildings and zeros
  for its box and counts. ``status`` is ``queued`` (the job waits or runs), ``done`` or ``failed`` (``error``
  says why, without server paths); every map stored before is ``done``. The parsed counts are the parse's
  progress (elements read, buildings so far), written at most once a second.
- ``jobs.request_id`` (migration 12): the id of the API request that queued the job (``X-Request-ID``, taken or
  made; a job queued by another job inherits its id), logged by the worker that runs it; NULL before.
"""

from __future__ import annotations

import re
import time

from db.connection import Database, transaction

MIGRATIONS: list[tuple[int, str, str]] = [
    (
        1,
        "initial schema",
        """
        CREATE TABLE maps (
            id INTEGER PRIMARY KEY AUTOINCREMENT,
            name TEXT NOT NULL,
            source_filename TEXT NOT NULL,
            source_format TEXT NOT NULL,
            source_path TEXT NOT NULL,
            sha256 TEXT NOT NULL,
            size_bytes INTEGER NOT NULL,
            min_lat REAL NOT NULL, min_lon REAL NOT NULL, max_lat REAL NOT NULL, max_lon REAL NOT NULL,
            origin_lat REAL NOT NULL, origin_lon REAL NOT NULL,
            building_count INTEGER NOT NULL,
            facade_count INTEGER NOT NULL,
            repair_report TEXT NOT NULL DEFAULT '{}',
            created_at REAL NOT NULL
        );
        CREATE INDEX maps_sha256 ON maps(sha256);

        CREATE TABLE buildings (
            map_id INTEGER NOT NULL REFERENCES maps(id) ON DELETE CASCADE,
            building_id INTEGER NOT NULL,
            osm_id TEXT,
            name TEXT,
            height_m REAL,
            footprint_geojson TEXT NOT NULL,
            footprint_local_wkb BLOB,
            PRIMARY KEY (map_id, building_id)
        ) WITHOUT ROWID;

        CREATE TABLE facades (
            map_id INTEGER PRIMARY KEY REFERENCES maps(id) ON DELETE CASCADE,
            facade_count INTEGER NOT NULL,
            arrays_npz BLOB NOT NULL
        );

        CREATE TABLE jobs (
            id INTEGER PRIMARY KEY AUTOINCREMENT,
            kind TEXT NOT NULL,
            payload TEXT NOT NULL DEFAULT '{}',
            status TEXT NOT NULL DEFAULT 'queued'
                CHECK (status IN ('queued', 'running', 'done', 'failed', 'cancelled')),
            priority INTEGER NOT NULL DEFAULT 0,
            attempts INTEGER NOT NULL DEFAULT 0,
            max_attempts INTEGER NOT NULL DEFAULT 3,
            run_after REAL NOT NULL DEFAULT 0,
            lease_owner TEXT,
            lease_expires_at REAL,
            heartbeat_at REAL,
            map_id INTEGER,
            reference_id INTEGER,
            result TEXT,
            error TEXT,
            created_at REAL NOT NULL,
            updated_at REAL NOT NULL,
            started_at REAL,
            finished_at REAL
        );
        CREATE INDEX jobs_claimable ON jobs(status, run_after, priority, id);
        CREATE INDEX jobs_reference ON jobs(reference_id);
        CREATE INDEX jobs_map ON jobs(map_id);

        CREATE TABLE workers (
            worker_id TEXT PRIMARY KEY,
            pid INTEGER NOT NULL,
            hostname TEXT NOT NULL,
            started_at REAL NOT NULL,
            heartbeat_at REAL NOT NULL,
            current_job_id INTEGER,
            stopped_at REAL
        );

        CREATE TABLE reference_images (
            id INTEGER PRIMARY KEY AUTOINCREMENT,
            map_id INTEGER NOT NULL REFERENCES maps(id) ON DELETE CASCADE,
            image_path TEXT NOT NULL,
            original_filename TEXT,
            sha256 TEXT NOT NULL,
            size_bytes INTEGER NOT NULL,
            image_format TEXT NOT NULL,
            width INTEGER NOT NULL,
            height INTEGER NOT NULL,
            gps_lat REAL NOT NULL,
            gps_lon REAL NOT NULL,
            position_source TEXT NOT NULL CHECK (position_source IN ('exif', 'request')),
            prior_heading_deg REAL,
            focal_length_35mm REAL,
            status TEXT NOT NULL DEFAULT 'queued'
                CHECK (status IN ('queued', 'processing', 'done', 'failed')),
            job_id INTEGER,
            estimated_lat REAL,
            estimated_lon REAL,
            estimated_heading_deg REAL,
            buildings_seen TEXT,
            timings TEXT,
            error TEXT,
            created_at REAL NOT NULL,
            updated_at REAL NOT NULL,
            UNIQUE (map_id, sha256)
        );

        CREATE TABLE labels (
            reference_id INTEGER PRIMARY KEY REFERENCES reference_images(id) ON DELETE CASCADE,
            identity_npz BLOB NOT NULL,
            created_at REAL NOT NULL
        );

        CREATE TABLE keypoints (
            reference_id INTEGER PRIMARY KEY REFERENCES reference_images(id) ON DELETE CASCADE,
            keypoint_count INTEGER NOT NULL,
            arrays_npz BLOB NOT NULL,
            created_at REAL NOT NULL
        );

        CREATE TABLE vocabularies (
            map_id INTEGER PRIMARY KEY REFERENCES maps(id) ON DELETE CASCADE,
            word_count INTEGER NOT NULL,
            arrays_npz BLOB NOT NULL,
            created_at REAL NOT NULL
        );

        CREATE TABLE sbow_documents (
            reference_id INTEGER PRIMARY KEY REFERENCES reference_images(id) ON DELETE CASCADE,
            map_id INTEGER NOT NULL REFERENCES maps(id) ON DELETE CASCADE,
            word_total REAL NOT NULL,
            created_at REAL NOT NULL
        );
        CREATE INDEX sbow_documents_map ON sbow_documents(map_id);

        CREATE TABLE sbow_postings (
            map_id INTEGER NOT NULL,
            word_id INTEGER NOT NULL,
            reference_id INTEGER NOT NULL REFERENCES sbow_documents(reference_id) ON DELETE CASCADE,
            weight REAL NOT NULL,
            PRIMARY KEY (map_id, word_id, reference_id)
        ) WITHOUT ROWID;
        CREATE INDEX sbow_postings_reference ON sbow_postings(reference_id);

        CREATE TABLE queries (
            id INTEGER PRIMARY KEY AUTOINCREMENT,
            map_id INTEGER NOT NULL REFERENCES maps(id) ON DELETE CASCADE,
            image_path TEXT,
            sha256 TEXT,
            params TEXT NOT NULL DEFAULT '{}',
            status TEXT NOT NULL DEFAULT 'queued'
                CHECK (status IN ('queued', 'processing', 'done', 'failed')),
            job_id INTEGER,
            result TEXT,
            error TEXT,
            created_at REAL NOT NULL,
            updated_at REAL NOT NULL
        );
        CREATE INDEX queries_map ON queries(map_id);
        """,
    ),
    (
        2,
        "map read options",
        """
        ALTER TABLE maps ADD COLUMN read_options TEXT NOT NULL DEFAULT '{}';
        """,
    ),
    (
        3,
        "sbow change log",
        """
        CREATE TABLE sbow_changes (
            seq INTEGER PRIMARY KEY AUTOINCREMENT,
            map_id INTEGER NOT NULL REFERENCES maps(id) ON DELETE CASCADE,
            reference_id INTEGER NOT NULL,
            changed_at REAL NOT NULL
        );
        CREATE INDEX sbow_changes_map ON sbow_changes(map_id, seq);
        INSERT INTO sbow_changes (map_id, reference_id, changed_at)
            SELECT map_id, reference_id, created_at FROM sbow_documents ORDER BY reference_id;
        """,
    ),
    (
        4,
        "job publication to a broker",
        """
        ALTER TABLE jobs ADD COLUMN published_at REAL;
        """,
    ),
    (
        5,
        "compass accuracy of a reference's heading prior",
        """
        ALTER TABLE reference_images ADD COLUMN prior_heading_accuracy_deg REAL;
        """,
    ),
    (
        6,
        "the attribution a map upload states",
        """
        ALTER TABLE maps ADD COLUMN attribution TEXT;
        """,
    ),
    (
        7,
        "reference sequences: capture time, device, sequence id, placement",
        """
        ALTER TABLE reference_images ADD COLUMN sequence_id TEXT;
        ALTER TABLE reference_images ADD COLUMN capture_time TEXT;
        ALTER TABLE reference_images ADD COLUMN device TEXT;
        ALTER TABLE reference_images ADD COLUMN placement TEXT NOT NULL DEFAULT 'alone';
        CREATE INDEX reference_images_sequence ON reference_images(map_id, sequence_id);
        """,
    ),
    (
        8,
        "tenants: the tenant of a map and of a job",
        """
        ALTER TABLE maps ADD COLUMN tenant TEXT;
        CREATE INDEX maps_tenant ON maps(tenant);
        ALTER TABLE jobs ADD COLUMN tenant TEXT;
        """,
    ),
    (
        9,
        "maps as jobs: a map's status, error, job and parse progress",
        """
        ALTER TABLE maps ADD COLUMN status TEXT NOT NULL DEFAULT 'done';
        ALTER TABLE maps ADD COLUMN error TEXT;
        ALTER TABLE maps ADD COLUMN error_code TEXT;
        ALTER TABLE maps ADD COLUMN error_details TEXT;
        ALTER TABLE maps ADD COLUMN job_id INTEGER;
        ALTER TABLE maps ADD COLUMN parsed_elements INTEGER NOT NULL DEFAULT 0;
        ALTER TABLE maps ADD COLUMN parsed_buildings INTEGER NOT NULL DEFAULT 0;
        """,
    ),
    (
        10,
        "tracks: a walk of query photos located together; its frames are query rows with track_id, frame_index",
        """
        CREATE TABLE tracks (
            id INTEGER PRIMARY KEY AUTOINCREMENT,
            map_id INTEGER NOT NULL REFERENCES maps(id) ON DELETE CASCADE,
            params TEXT NOT NULL DEFAULT '{}',
            status TEXT NOT NULL DEFAULT 'queued'
                CHECK (status IN ('queued', 'processing', 'done', 'failed')),
            job_id INTEGER,
            result TEXT,
            error TEXT,
            created_at REAL NOT NULL,
            updated_at REAL NOT NULL
        );
        CREATE INDEX tracks_map ON tracks(map_id);
        ALTER TABLE queries ADD COLUMN track_id INTEGER REFERENCES tracks(id) ON DELETE CASCADE;
        ALTER TABLE queries ADD COLUMN frame_index INTEGER;
        CREATE INDEX queries_track ON queries(track_id, frame_index);
        """,
    ),
    (
        11,
        "workers: the job kinds each worker claims (NULL: every kind); /readyz counts those that take queries",
        """
        ALTER TABLE workers ADD COLUMN kinds TEXT;
        """,
    ),
    (
        12,
        "request ids: the API request that queued a job, logged by the worker that runs it",
        """
        ALTER TABLE jobs ADD COLUMN request_id TEXT;
        """,
    ),
]

LATEST_VERSION = MIGRATIONS[-1][0]


_POSTGRES_TYPES = (
    (re.compile(r"\bINTEGER PRIMARY KEY AUTOINCREMENT\b"), "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY"),
    (re.compile(r"\bINTEGER\b"), "BIGINT"),
    (re.compile(r"\bREAL\b"), "DOUBLE PRECISION"),
    (re.compile(r"\bBLOB\b"), "BYTEA"),
    (re.compile(r"\)\s*WITHOUT ROWID"), ")"),
)
MIGRATION_LOCK = "geoloc:migrations"


def portable_ddl(statement: str, dialect: str) -> str:
    """One DDL statement for ``dialect`` (``"sqlite"``: as written; ``"postgresql"``: types rendered).

    Parameters
    ----------
    statement
        A statement of :data:`MIGRATIONS` (SQLite's words).
    dialect
        ``"sqlite"`` or ``"postgresql"``.

    Returns
    -------
    str
        The statement to run on that engine.
    """
    if dialect != "postgresql":
        return statement
    for pattern, replacement in _POSTGRES_TYPES:
        statement = pattern.sub(replacement, statement)
    return statement


def schema_version(db: Database) -> int:
    """The applied schema version (0 for a new database)."""
    if not db.is_postgres:
        return int(db.execute("PRAGMA user_version").fetchone()[0])
    exists = db.execute("SELECT to_regclass('schema_migrations') IS NOT NULL").fetchone()[0]
    if not exists:
        return 0
    return int(db.execute("SELECT COALESCE(MAX(version), 0) FROM schema_migrations").fetchone()[0])


def _split_statements(script: str) -> list[str]:
    return [statement.strip() for statement in script.split(";") if statement.strip()]


def migrate(db: Database) -> int:
    """Apply every migration newer than the database's version; returns the version after."""
    for version, name, script in MIGRATIONS:
        if schema_version(db) >= version:
            continue
        with transaction(db):
            db.lock(MIGRATION_LOCK)
            db.execute(
                portable_ddl(
                    "CREATE TABLE IF NOT EXISTS schema_migrations ("
                    "version INTEGER PRIMARY KEY, name TEXT NOT NULL, applied_at REAL NOT NULL)",
                    db.dialect,
                )
            )
            if schema_version(db) >= version:  # another process won the race
                continue
            for statement in _split_statements(script):
                db.execute(portable_ddl(statement, db.dialect))
            db.execute(
                "INSERT INTO schema_migrations (version, name, applied_at) VALUES (?, ?, ?)",
                (version, name, time.time()),
            )
            if not db.is_postgres:
                db.execute(f"PRAGMA user_version = {int(version)}")
    return schema_version(db)
