"""The semantic bag-of-words index: a vocabulary per map and an inverted index.

Tables: ``vocabularies(map_id, arrays_npz)`` (the visual words, e.g. cluster centres),
``sbow_documents(reference_id, map_id, word_total)`` (one row per indexed reference) and
``sbow_postings(map_id, word_id, reference_id, weight)`` (the inverted index; ``weight`` is the
term weight, e.g. the count or identity-weighted count of the word in the reference).

Consistency: postings cascade from their document row, which cascades from the reference, so
deleting a reference removes it from the index in the same statement; :func:`index_reference`
replaces a reference's document and postings atomically (call it inside the transaction that
stores the reference's keypoints). Document frequencies are computed from the postings at query
time, so there are no counters to drift. Scoring is the method's (``geoloc.localize.retrieval.tfidf_scores``)
on the arrays of :func:`postings_for_words`.

Change log: ``sbow_changes(seq, map_id, reference_id)`` gets a row in the same transaction as every
change of a reference's postings (:func:`index_reference`, and :func:`db.references.delete_reference`
through :func:`log_change`). A process that keeps the index in memory reads the whole index once
(:func:`index_snapshot`, which also gives the log's high-water mark at that instant) and then, before
each use, the references changed past its mark (:func:`changes_after`, :func:`document_postings`). All
of it is plain SQL over these tables (a sequence, ``>`` and ``IN``), so it ports to another database.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from db.blobs import pack_arrays, unpack_arrays
from db.connection import Database


def save_vocabulary(db: Database, map_id: int, arrays: dict[str, np.ndarray]) -> None:
    """Store (replace) a map's vocabulary; ``arrays['centers']`` (W, D) gives the word count."""
    word_count = len(arrays["centers"]) if "centers" in arrays else len(next(iter(arrays.values())))
    db.execute(
        "INSERT INTO vocabularies (map_id, word_count, arrays_npz, created_at) VALUES (?, ?, ?, ?)"
        " ON CONFLICT (map_id) DO UPDATE SET word_count = excluded.word_count, arrays_npz = excluded.arrays_npz,"
        " created_at = excluded.created_at",
        (map_id, word_count, pack_arrays(arrays), time.time()),
    )


def vocabulary_stamp(db: Database, map_id: int) -> float | None:
    """When a map's vocabulary was stored (a replaced one gets a new time), or None."""
    row = db.execute("SELECT created_at FROM vocabularies WHERE map_id = ?", (map_id,)).fetchone()
    return float(row[0]) if row else None


def load_vocabulary(db: Database, map_id: int) -> dict[str, np.ndarray] | None:
    """A map's vocabulary arrays, or None."""
    row = db.execute("SELECT arrays_npz FROM vocabularies WHERE map_id = ?", (map_id,)).fetchone()
    return unpack_arrays(row[0]) if row else None


def index_reference(db: Database, map_id: int, reference_id: int, word_ids: np.ndarray, weights: np.ndarray) -> int:
    """Replace a reference's postings with (word_id, weight) pairs; call inside a transaction.

    Duplicate words are summed. Returns the number of distinct words.
    """
    word_ids = np.asarray(word_ids, dtype=np.int64).ravel()
    weights = np.asarray(weights, dtype=float).ravel()
    if word_ids.shape != weights.shape:
        raise ValueError("word_ids and weights must have the same length")
    unique_words, inverse = np.unique(word_ids, return_inverse=True)
    summed = np.bincount(inverse, weights=weights, minlength=len(unique_words)) if len(word_ids) else np.zeros(0)
    db.execute("DELETE FROM sbow_documents WHERE reference_id = ?", (reference_id,))
    db.execute(
        "INSERT INTO sbow_documents (reference_id, map_id, word_total, created_at) VALUES (?, ?, ?, ?)",
        (reference_id, map_id, float(summed.sum()), time.time()),
    )
    db.executemany(
        "INSERT INTO sbow_postings (map_id, word_id, reference_id, weight) VALUES (?, ?, ?, ?)",
        [(map_id, int(w), reference_id, float(s)) for w, s in zip(unique_words, summed, strict=True)],
    )
    log_change(db, map_id, reference_id)
    return len(unique_words)


def log_change(db: Database, map_id: int, reference_id: int) -> None:
    """Record that a reference's postings changed (indexed, re-indexed or deleted).

    Call inside the transaction that changes them.
    """
    db.execute(
        "INSERT INTO sbow_changes (map_id, reference_id, changed_at) VALUES (?, ?, ?)",
        (map_id, reference_id, time.time()),
    )


def change_mark(db: Database, map_id: int) -> int:
    """The high-water mark of a map's change log (0 when nothing was ever indexed)."""
    row = db.execute("SELECT MAX(seq) FROM sbow_changes WHERE map_id = ?", (map_id,)).fetchone()
    return int(row[0] or 0)


def changes_after(db: Database, map_id: int, after_seq: int) -> list[tuple[int, int]]:
    """(seq, reference_id) of a map's index changes with ``seq > after_seq``, oldest first."""
    rows = db.execute(
        "SELECT seq, reference_id FROM sbow_changes WHERE map_id = ? AND seq > ? ORDER BY seq", (map_id, after_seq)
    ).fetchall()
    return [(int(seq), int(reference_id)) for seq, reference_id in rows]


@contextmanager
def _read_snapshot(db: Database) -> Iterator[None]:
    """Statements inside see one state of the database (a deferred transaction: no write lock)."""
    # PostgreSQL's default READ COMMITTED would let each statement see another state.
    db.execute("BEGIN ISOLATION LEVEL REPEATABLE READ" if db.is_postgres else "BEGIN")
    try:
        yield
    finally:
        db.execute("COMMIT")


@dataclass
class IndexSnapshot:
    """A map's whole inverted index at change-log mark ``mark``, as arrays.

    ids: (D,) sorted reference ids of the indexed documents; lengths: (D,) their word totals;
    word, doc, weight: one entry per postings row, ``doc`` indexing ``ids``.
    """

    mark: int
    ids: np.ndarray
    lengths: np.ndarray
    word: np.ndarray
    doc: np.ndarray
    weight: np.ndarray
    recent_changes: list[tuple[int, int]]


def index_snapshot(db: Database, map_id: int, *, lookback: int = 0, chunk_rows: int = 1 << 20) -> IndexSnapshot:
    """Every document and postings row of a map's index, read in one snapshot with the log's mark.

    Also the log's rows within ``lookback`` of the mark (the changes the snapshot already holds).

    Rows come in primary-key order (word, then reference) and are kept in narrow arrays (int32 words and
    documents; float32 weights where exact, as word counts are): about 12 bytes per row.
    """
    words, docs, weights = [], [], []
    with _read_snapshot(db):
        mark = change_mark(db, map_id)
        recent_changes = changes_after(db, map_id, mark - lookback) if lookback > 0 else []
        documents = db.execute(
            "SELECT reference_id, word_total FROM sbow_documents WHERE map_id = ? ORDER BY reference_id", (map_id,)
        ).fetchall()
        ids = np.array([r[0] for r in documents], np.int64)
        lengths = np.array([r[1] for r in documents], np.float64)
        cursor = db.execute(
            "SELECT word_id, reference_id, weight FROM sbow_postings WHERE map_id = ?"
            " ORDER BY map_id, word_id, reference_id",
            (map_id,),
        )
        while rows := cursor.fetchmany(chunk_rows):
            chunk = np.fromiter(itertools.chain.from_iterable(rows), np.float64, 3 * len(rows)).reshape(-1, 3)
            words.append(chunk[:, 0].astype(np.int32))
            docs.append(np.searchsorted(ids, chunk[:, 1].astype(np.int64)).astype(np.int32))
            single = chunk[:, 2].astype(np.float32)
            weights.append(single if np.array_equal(single, chunk[:, 2]) else chunk[:, 2].copy())
    weight_type = np.float32 if all(w.dtype == np.float32 for w in weights) else np.float64
    return IndexSnapshot(
        mark,
        ids,
        lengths,
        np.concatenate(words) if words else np.zeros(0, np.int32),
        np.concatenate(docs) if docs else np.zeros(0, np.int32),
        np.concatenate(weights).astype(weight_type, copy=False) if weights else np.zeros(0, np.float32),
        recent_changes,
    )


def document_postings(
    db: Database, map_id: int, reference_ids: list[int]
) -> dict[int, tuple[np.ndarray, np.ndarray, float]]:
    """The current postings of some references of a map: {reference id: (words, weights, word total)}.

    References without a document (deleted, or not indexed) are left out.
    """
    out: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}
    with _read_snapshot(db):
        for start in range(0, len(reference_ids), 500):
            chunk = [int(r) for r in reference_ids[start : start + 500]]
            marks = ", ".join("?" for _ in chunk)
            totals = db.execute(
                f"SELECT reference_id, word_total FROM sbow_documents WHERE map_id = ? AND reference_id IN ({marks})",
                [map_id, *chunk],
            ).fetchall()
            rows = db.execute(
                f"SELECT reference_id, word_id, weight FROM sbow_postings WHERE reference_id IN ({marks})"
                " ORDER BY reference_id, word_id",
                chunk,
            ).fetchall()
            by_reference: dict[int, list[tuple[int, float]]] = {}
            for reference_id, word_id, weight in rows:
                by_reference.setdefault(int(reference_id), []).append((int(word_id), float(weight)))
            for reference_id, total in totals:
                pairs = by_reference.get(int(reference_id), [])
                out[int(reference_id)] = (
                    np.array([w for w, _ in pairs], np.int64),
                    np.array([c for _, c in pairs], np.float64),
                    float(total),
                )
    return out


def vocabulary_size(db: Database, map_id: int) -> int | None:
    """Number of words of a map's stored vocabulary, or None."""
    row = db.execute("SELECT word_count FROM vocabularies WHERE map_id = ?", (map_id,)).fetchone()
    return int(row[0]) if row else None


def document_count(db: Database, map_id: int) -> int:
    """Number of indexed references of a map."""
    return int(db.execute("SELECT COUNT(*) FROM sbow_documents WHERE map_id = ?", (map_id,)).fetchone()[0])


@dataclass
class Postings:
    """The postings of some query words, as arrays for ``geoloc.localize.retrieval.tfidf_scores``.

    ``word``, ``doc``, ``count``: one entry per (word, reference) row, ``doc`` indexing ``reference_ids``
    and ``doc_lengths`` (total word count of each reference); ``n_docs``: indexed references of the map.
    """

    word: np.ndarray
    doc: np.ndarray
    count: np.ndarray
    reference_ids: np.ndarray
    doc_lengths: np.ndarray
    n_docs: int


def postings_for_words(db: Database, map_id: int, word_ids: np.ndarray) -> Postings:
    """Every postings row of the given words in a map's index (all of them, so df is exact)."""
    unique_words = np.unique(np.asarray(word_ids, dtype=np.int64).ravel())
    rows: list[tuple[int, int, float]] = []
    chunk = 500
    for start in range(0, len(unique_words), chunk):
        words = unique_words[start : start + chunk].tolist()
        placeholders = ", ".join("?" for _ in words)
        rows += db.execute(
            f"SELECT word_id, reference_id, weight FROM sbow_postings WHERE map_id = ? AND word_id IN ({placeholders})",
            [map_id, *words],
        ).fetchall()
    reference_ids = np.array(sorted({r[1] for r in rows}), dtype=np.int64)
    lengths = dict(
        db.execute("SELECT reference_id, word_total FROM sbow_documents WHERE map_id = ?", (map_id,)).fetchall()
    )
    position = {int(ref): i for i, ref in enumerate(reference_ids)}
    return Postings(
        word=np.array([r[0] for r in rows], dtype=np.int64),
        doc=np.array([position[r[1]] for r in rows], dtype=np.int64),
        count=np.array([r[2] for r in rows], dtype=np.float64),
        reference_ids=reference_ids,
        doc_lengths=np.array([lengths.get(int(ref), 0.0) for ref in reference_ids], dtype=np.float64),
        n_docs=len(lengths),
    )
