"""The semantic bag-of-words index: a vocabulary per map and an inverted index.

Tables: ``vocabularies(map_id, arrays_npz)`` (the visual words, e.g. cluster centres),
``sbow_documents(reference_id, map_id, word_total)`` (one row per indexed reference) and
``sbow_postings(map_id, word_id, reference_id, weight)`` (the inverted index; ``weight`` is the
term weight, e.g. the count or identity-weighted count of the word in the reference).

Consistency: postings cascade from their document row, which cascades from the reference, so
deleting a reference removes it from the index in the same statement; :func:`index_reference`
replaces a reference's document and postings atomically (call it inside the transaction that
stores the reference's keypoints). Document frequencies are computed from the postings at query
time, so there are no counters to drift. Scoring is the method's (``geoloc.retrieval.tfidf_scores``)
on the arrays of :func:`postings_for_words`.
"""

from __future__ import annotations

import time
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


def load_vocabulary(db: Database, map_id: int) -> dict[str, np.ndarray] | None:
    """A map's vocabulary arrays, or None."""
    row = db.execute("SELECT arrays_npz FROM vocabularies WHERE map_id = ?", (map_id,)).fetchone()
    return unpack_arrays(row[0]) if row else None


def index_reference(db: Database, map_id: int, reference_id: int, word_ids: np.ndarray, weights: np.ndarray) -> int:
    """Replace a reference's postings with (word_id, weight) pairs (duplicates summed); returns the
    number of distinct words. Call inside a transaction."""
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
    return len(unique_words)


def document_count(db: Database, map_id: int) -> int:
    """Number of indexed references of a map."""
    return int(db.execute("SELECT COUNT(*) FROM sbow_documents WHERE map_id = ?", (map_id,)).fetchone()[0])


@dataclass
class Postings:
    """The postings of some query words, as arrays for ``geoloc.retrieval.tfidf_scores``.

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
