"""Reference photos (table ``reference_images``), their labels and keypoints.

The image file lives at ``GEOLOC_DATA_DIR/<image_path>`` (``images/<map_id>/<sha256>.<ext>``);
``(map_id, sha256)`` is unique. ``status`` is written by the method's handler (``done``) or the
worker machinery; the API reports the job's state while the reference is not finished
(:func:`contracts.jobs.reported_status`). Labels and keypoints are npz blobs in the format of
:mod:`contracts.references`, replaced as a whole so that a re-run of a job (after a crash) overwrites
rather than duplicates.
"""

from __future__ import annotations

import io
import json
import time
from typing import Any, cast

import numpy as np

from contracts.jobs import WORK_STATUSES, reported_status
from contracts.references import ReferenceKeypoints, ReferenceLabelArrays, WalkFrameArrays
from db.blobs import pack_arrays, unpack_arrays
from db.connection import Database
from db.jobs import cancel_queued_jobs
from db.records import NewReference, ReferenceLabel
from db.rows import ReferenceRow
from db.sbow import log_change

_JSON_COLUMNS = ("buildings_seen", "timings")


def _decode(row: dict[str, Any]) -> ReferenceRow:
    row = dict(row)
    for column in _JSON_COLUMNS:
        row[column] = json.loads(row[column]) if row.get(column) else None
    return cast(ReferenceRow, row)


def insert_reference(db: Database, reference: NewReference) -> int:
    """Insert a queued reference (:class:`db.records.NewReference`); returns its id. Call inside a transaction."""
    now = time.time()
    return db.insert_returning_id(
        "INSERT INTO reference_images (map_id, image_path, original_filename, sha256, size_bytes,"
        " image_format, width, height, gps_lat, gps_lon, position_source, prior_heading_deg,"
        " prior_heading_accuracy_deg, focal_length_35mm, sequence_id, capture_time, device, status,"
        " created_at, updated_at)"
        " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'queued', ?, ?)",
        (
            reference.map_id,
            reference.image_path,
            reference.original_filename,
            reference.sha256,
            reference.size_bytes,
            reference.image_format,
            reference.width,
            reference.height,
            reference.gps_lat,
            reference.gps_lon,
            reference.position_source,
            reference.prior_heading_deg,
            reference.prior_heading_accuracy_deg,
            reference.focal_length_35mm,
            reference.sequence_id,
            reference.capture_time,
            reference.device,
            now,
            now,
        ),
    )


def set_reference_job(db: Database, reference_id: int, job_id: int) -> None:
    """Link a reference to the job that processes it."""
    db.execute(
        "UPDATE reference_images SET job_id = ?, updated_at = ? WHERE id = ?",
        (job_id, time.time(), reference_id),
    )


def get_reference(db: Database, reference_id: int) -> ReferenceRow | None:
    """One reference (JSON columns decoded), or None."""
    rows = list(db.query("SELECT * FROM reference_images WHERE id = ?", (reference_id,)))
    return _decode(rows[0]) if rows else None


def find_reference_by_sha256(db: Database, map_id: int, sha256: str) -> ReferenceRow | None:
    """The reference of this map with this image checksum, or None."""
    rows = list(db.query("SELECT * FROM reference_images WHERE map_id = ? AND sha256 = ?", (map_id, sha256)))
    return _decode(rows[0]) if rows else None


def list_references(db: Database, map_id: int, *, status: str | None = None) -> list[ReferenceRow]:
    """References of a map, oldest first, optionally of one status."""
    if status is None:
        rows = db.query("SELECT * FROM reference_images WHERE map_id = ? ORDER BY id", (map_id,))
    else:
        rows = db.query("SELECT * FROM reference_images WHERE map_id = ? AND status = ? ORDER BY id", (map_id, status))
    return [_decode(row) for row in rows]


def list_references_after(db: Database, map_id: int, *, after_id: int = 0, limit: int = 100) -> list[ReferenceRow]:
    """One page of a map's references: up to ``limit`` with ids above ``after_id``, by id (keyset paging)."""
    rows = db.query(
        "SELECT * FROM reference_images WHERE map_id = ? AND id > ? ORDER BY id LIMIT ?", (map_id, after_id, limit)
    )
    return [_decode(row) for row in rows]


def effective_status_counts(db: Database, map_id: int) -> dict[str, int]:
    """Number of a map's references per reported status (:func:`contracts.jobs.reported_status`)."""
    rows = db.query(
        "SELECT r.status AS status, r.error AS error, j.status AS job_status, j.attempts AS attempts,"
        " j.error AS job_error FROM reference_images r LEFT JOIN jobs j ON j.id = r.job_id WHERE r.map_id = ?",
        (map_id,),
    )
    counts: dict[str, int] = dict.fromkeys(WORK_STATUSES, 0)
    for row in rows:
        state, _ = reported_status(row["status"], row["error"], row["job_status"], row["attempts"], row["job_error"])
        counts[state] += 1
    return counts


_WALK_CANDIDATE = "(sequence_id IS NOT NULL OR (capture_time IS NOT NULL AND device IS NOT NULL))"
"""SQL of :func:`may_join_walk` (the grouping's rule, :mod:`geoloc.localize.sequence.grouping`)."""


def may_join_walk(row: ReferenceRow) -> bool:
    """Whether a reference can be grouped into a walk: a sequence id, or a capture time and a named camera."""
    return row["sequence_id"] is not None or (row["capture_time"] is not None and row["device"] is not None)


def sequence_candidates(db: Database, map_id: int) -> list[ReferenceRow]:
    """The map's references that may belong to a walk (:func:`may_join_walk`), oldest first."""
    rows = db.query(f"SELECT * FROM reference_images WHERE map_id = ? AND {_WALK_CANDIDATE} ORDER BY id", (map_id,))
    return [_decode(row) for row in rows]


def set_reference_placement(db: Database, reference_id: int, placement: str) -> None:
    """Record whether a reference's pose is its own label's (``alone``) or its sequence's (``sequence``)."""
    db.execute(
        "UPDATE reference_images SET placement = ?, updated_at = ? WHERE id = ?", (placement, time.time(), reference_id)
    )


def update_reference_result(
    db: Database,
    reference_id: int,
    *,
    status: str,
    estimated_lat: float | None = None,
    estimated_lon: float | None = None,
    estimated_heading_deg: float | None = None,
    buildings_seen: list[dict[str, Any]] | None = None,
    timings: dict[str, float] | None = None,
    error: str | None = None,
) -> bool:
    """Write the outcome of processing a reference; False if it no longer exists."""
    cursor = db.execute(
        "UPDATE reference_images SET status = ?, estimated_lat = ?, estimated_lon = ?,"
        " estimated_heading_deg = ?, buildings_seen = ?, timings = ?, error = ?, updated_at = ?"
        " WHERE id = ?",
        (
            status,
            estimated_lat,
            estimated_lon,
            estimated_heading_deg,
            json.dumps(buildings_seen) if buildings_seen is not None else None,
            json.dumps(timings) if timings is not None else None,
            error,
            time.time(),
            reference_id,
        ),
    )
    return cursor.rowcount == 1


def save_label(db: Database, label: ReferenceLabel) -> None:
    """Store a labelled reference (:class:`db.records.ReferenceLabel`): its arrays, keypoints, answer, placement.

    The reference is then ``done``. Its four writes are one unit: call inside a transaction (the caller's, which
    may hold more: a label job's index postings, a walk's other references); raises ``RuntimeError`` outside one.
    """
    if not db.in_transaction:
        raise RuntimeError("save_label writes four tables as one unit: call it inside a transaction")
    reference_id = label.reference_id
    save_labels(db, reference_id, label.arrays, label.walk_frame)
    save_keypoints(db, reference_id, label.keypoints)
    update_reference_result(
        db,
        reference_id,
        status="done",
        estimated_lat=label.estimated_lat,
        estimated_lon=label.estimated_lon,
        estimated_heading_deg=label.estimated_heading_deg,
        buildings_seen=label.buildings_seen,
        timings=label.timings,
    )
    set_reference_placement(db, reference_id, label.placement)


def delete_reference(db: Database, reference_id: int) -> ReferenceRow | None:
    """Delete a reference and cancel its queued jobs; call inside a transaction.

    Its labels, keypoints and index postings cascade. Returns the deleted row (its ``image_path`` is
    to be removed after commit), or None.
    """
    row = get_reference(db, reference_id)
    if row is None:
        return None
    cancel_queued_jobs(db, reference_id=reference_id)
    if db.execute("SELECT 1 FROM sbow_documents WHERE reference_id = ?", (reference_id,)).fetchone():
        log_change(db, row["map_id"], reference_id)  # its postings go with it (cascade)
    db.execute("DELETE FROM reference_images WHERE id = ?", (reference_id,))
    return row


WALK_FRAME_PREFIX = "walk_"
"""Prefix of the members of a labels blob that hold a walk reference's label alone (the sequence job reads them)."""


def save_labels(
    db: Database, reference_id: int, labels: ReferenceLabelArrays, walk_frame: WalkFrameArrays | None = None
) -> None:
    """Store (replace) a reference's identity map arrays, and the arrays of its label alone when it may join a walk.

    walk_frame: what the sequence job needs of the reference labelled alone
    (:class:`contracts.references.WalkFrameArrays`), stored in the same blob under
    :data:`WALK_FRAME_PREFIX` (no schema change; it goes with the labels row, deleted with the reference). A blob
    with a walk frame is stored uncompressed: zlib on its float32 descriptors cost 15 ms of CPU per label job
    (a 180 kB blob; 660 kB uncompressed, packed in 1 ms).
    """
    arrays = labels.to_arrays()
    if walk_frame is not None:
        arrays.update({WALK_FRAME_PREFIX + name: value for name, value in walk_frame.to_arrays().items()})
    db.execute(
        "INSERT INTO labels (reference_id, identity_npz, created_at) VALUES (?, ?, ?) ON CONFLICT (reference_id)"
        " DO UPDATE SET identity_npz = excluded.identity_npz, created_at = excluded.created_at",
        (reference_id, pack_arrays(arrays, compress=walk_frame is None), time.time()),
    )


def _labels_blob(db: Database, reference_id: int) -> bytes | None:
    row = db.execute("SELECT identity_npz FROM labels WHERE reference_id = ?", (reference_id,)).fetchone()
    return bytes(row[0]) if row else None


def load_labels(db: Database, reference_id: int) -> ReferenceLabelArrays | None:
    """A reference's identity map arrays, or None (the walk frame's members are not decompressed)."""
    blob = _labels_blob(db, reference_id)
    if blob is None:
        return None
    with np.load(io.BytesIO(blob), allow_pickle=False) as npz:
        return ReferenceLabelArrays.from_arrays(npz)


def load_walk_frame(db: Database, reference_id: int) -> WalkFrameArrays | None:
    """The arrays of a reference's label alone stored by :func:`save_labels`, or None (labelled without them)."""
    blob = _labels_blob(db, reference_id)
    if blob is None:
        return None
    with np.load(io.BytesIO(blob), allow_pickle=False) as npz:
        names = [name for name in npz.files if name.startswith(WALK_FRAME_PREFIX)]
        if not names:
            return None
        return WalkFrameArrays.from_arrays({name[len(WALK_FRAME_PREFIX) :]: npz[name] for name in names})


def save_keypoints(db: Database, reference_id: int, keypoints: ReferenceKeypoints) -> None:
    """Store (replace) a reference's keypoints: positions, descriptors, identity probabilities, anchors."""
    db.execute(
        "INSERT INTO keypoints (reference_id, keypoint_count, arrays_npz, created_at) VALUES (?, ?, ?, ?)"
        " ON CONFLICT (reference_id) DO UPDATE SET keypoint_count = excluded.keypoint_count,"
        " arrays_npz = excluded.arrays_npz, created_at = excluded.created_at",
        (reference_id, len(keypoints), pack_arrays(keypoints.to_arrays()), time.time()),
    )


def load_keypoints(db: Database, reference_id: int) -> ReferenceKeypoints | None:
    """A reference's keypoints, or None."""
    row = db.execute("SELECT arrays_npz FROM keypoints WHERE reference_id = ?", (reference_id,)).fetchone()
    return ReferenceKeypoints.from_arrays(unpack_arrays(row[0])) if row else None


def _keypoint_column(db: Database, column: str, reference_ids: list[int]) -> list[tuple[Any, Any]]:
    """(reference id, ``column``) of the keypoints rows of these references, 500 ids per statement."""
    rows: list[tuple[Any, Any]] = []
    for start in range(0, len(reference_ids), 500):
        chunk = reference_ids[start : start + 500]
        marks = ", ".join("?" for _ in chunk)
        cursor = db.execute(f"SELECT reference_id, {column} FROM keypoints WHERE reference_id IN ({marks})", chunk)
        rows += cursor.fetchall()
    return rows


def keypoint_stamps(db: Database, reference_ids: list[int]) -> dict[int, float]:
    """{reference id: when its keypoints were stored} for those of these references that have keypoints.

    A re-labelled reference gets a new time: a cached decoded copy is then stale.
    """
    return {int(ref): float(stamp) for ref, stamp in _keypoint_column(db, "created_at", reference_ids)}


def keypoint_positions(db: Database, reference_ids: list[int]) -> dict[int, np.ndarray]:
    """{reference id: its stored (2,) position} for those of these references that have keypoints.

    Only the position member of each blob is decompressed (:meth:`ReferenceKeypoints.position_from_arrays`;
    NaN for references stored before positions were).
    """
    positions = {}
    for ref, blob in _keypoint_column(db, "arrays_npz", reference_ids):
        with np.load(io.BytesIO(bytes(blob)), allow_pickle=False) as npz:
            positions[int(ref)] = ReferenceKeypoints.position_from_arrays(npz)
    return positions
