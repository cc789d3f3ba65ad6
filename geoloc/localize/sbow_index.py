"""An in-memory SBoW index for many references: word-major sparse postings scored by a compiled kernel.

The database's inverted index (``db/sbow.py``) is the source of truth; reading every posting of a query's
words from it costs time in the number of references (measured: 0.7 s at 10,000 references). This index
holds the same postings in memory, as a sparse matrix by word (CSR: for word w, the documents that have
it and their weights), and ranks exactly as :func:`geoloc.localize.retrieval.tfidf_scores` does on the database's
postings: same formula, same float64 operations in the same order (each document's score sums its words in
increasing word id), the same document frequencies (live documents only) and the same ties (lower id
first). A test compares the two rankings.

Changes are incremental: :meth:`SbowIndex.upsert` appends the document to a small *recent* store (document
by document, scored per document against the query's dense tf and idf) and tombstones any older copy;
:meth:`SbowIndex.remove` tombstones. When the recent store or the tombstones grow past a share of the base,
the base is rebuilt from memory (:meth:`SbowIndex.compact`, counting sorts: linear time). The caller keeps
the index in step with the database (``workers/reference_store.py``: a change log read past a high-water
mark).

Memory: per posting 4 bytes of document index, 4 (or 8) of weight and 2 of word (the document's word
list, to forget it when it is removed); weights are float32 when that is exact, as the service's integer
word counts are. 100,000 references of ~340 distinct words: 350 MB (``benchmarks/bench_sbow.py``).

The one SBoW index (decided in issue 18): there were three, this one (the workers' path, measured at 100 k
references), an in-memory ``InvertedIndex`` in :mod:`geoloc.localize.retrieval` (the evaluation's) and the SQL
ranking of ``db/sbow.py``. This one stays, as the shipped and measured one; the evaluation ranks with it too
(:class:`geoloc.evaluation.store.InMemoryReferenceStore`, documents added with :meth:`SbowIndex.add_words`),
which gives the scores ``InvertedIndex`` gave: both compute :func:`geoloc.localize.retrieval.tfidf_scores`
with each document's terms summed in increasing word order from 0.0, and the evaluation's ids are numbered
in insertion order so that ties (lower id first) fall as ``InvertedIndex``'s did (earlier insertion first).
The database keeps the postings as the source of truth; :func:`geoloc.localize.retrieval.tfidf_scores` stays
as the formula's specification, the reference of the tests. The storage is :mod:`geoloc.localize.sbow_segments`.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable

import numba
import numpy as np

from geoloc.localize.retrieval import bag, idf
from geoloc.localize.sbow_segments import RecentDocuments, Segment

COMPACT_RECENT_SHARE = 0.05
"""The recent segment is merged into the base when it holds more than this share of the base's documents."""
COMPACT_MIN_RECENT = 2048
"""... and at least this many documents (small indexes live in the recent segment alone)."""
COMPACT_DEAD_SHARE = 0.2
"""The base is rebuilt when this share of its documents has been removed or replaced."""


class SbowIndex:
    """In-memory SBoW index over ``n_words`` visual words with integer document ids (reference ids).

    Scores and ranks as :func:`geoloc.localize.retrieval.tfidf_scores` on the postings (module docstring). The base
    segment is scored word by word (the postings of the query's words), the recent documents document by
    document (each document's words looked up in the query's dense tf and idf): both add each document's
    terms in increasing word order, the order of the database path. Not thread-safe: one per worker process
    (and map).
    """

    def __init__(self, n_words: int) -> None:
        self.n_words = int(n_words)
        self._base = Segment.empty(self.n_words)
        self._base_order: np.ndarray | None = None  # rows by increasing id; None: the base's ids are sorted
        self._base_keys = self._base.ids  # the base's ids, sorted
        self._base_df = np.zeros(self.n_words, np.int64)  # live postings per word in the base
        self._dead = 0
        self._recent = RecentDocuments(self.n_words)

    # -- contents ----------------------------------------------------------------------------------

    def __len__(self) -> int:
        """Number of live documents."""
        return len(self._base.ids) - self._dead + len(self._recent)

    def __contains__(self, doc_id: Hashable) -> bool:
        """Whether ``doc_id`` is a live document."""
        if doc_id in self._recent.row_of:
            return True
        return isinstance(doc_id, int | np.integer) and self._base_row(int(doc_id)) is not None

    @property
    def doc_ids(self) -> np.ndarray:
        """Sorted ids of the documents in the index."""
        recent = self._recent
        return np.sort(
            np.concatenate([self._base.ids[self._base.live], recent.ids[: recent.rows][recent.live[: recent.rows]]])
        )

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays of the index (postings, documents, frequencies)."""
        return self._base.nbytes + self._base_df.nbytes + self._recent.nbytes

    def postings(self, doc_id: int) -> tuple[np.ndarray, np.ndarray, float]:
        """A document's distinct words (sorted), their weights (float64) and its word total."""
        doc_id = int(doc_id)
        recent = self._recent
        if doc_id in recent.row_of:
            r = recent.row_of[doc_id]
            rows = slice(recent.ptr[r], recent.ptr[r + 1])
            return recent.words[rows].astype(np.int64), recent.weights[rows].copy(), float(recent.length[r])
        row = self._base_row(doc_id)
        if row is None:
            raise KeyError(doc_id)
        base = self._base
        words = np.sort(base.words_of(row))
        rows_of = np.array(
            [base.word_ptr[w] + np.searchsorted(base.doc[base.word_ptr[w] : base.word_ptr[w + 1]], row) for w in words],
            np.int64,
        )
        return words, base.weight[rows_of].astype(np.float64), float(base.length[row])

    def load(
        self,
        ids: np.ndarray,
        lengths: np.ndarray,
        post_word: np.ndarray,
        post_doc: np.ndarray,
        post_weight: np.ndarray,
    ) -> None:
        """Replace the contents with documents ``ids`` (word totals ``lengths``) and their postings rows.

        ``post_doc`` indexes ``ids``; the bulk load of a map's whole index.
        """
        ids = np.asarray(ids, np.int64)
        if len(np.unique(ids)) != len(ids):
            raise ValueError("document ids must be distinct")
        self.load_segment(Segment.from_postings(self.n_words, ids, lengths, post_word, post_doc, post_weight))

    def load_segment(self, segment: Segment) -> None:
        """Replace the contents with a base segment built earlier (:meth:`load`'s, or one mapped from a file).

        The segment's arrays are only read (but ``live``, which removals write), so read-only memory-mapped ones
        stay shared between the processes that map the same file.
        """
        if len(segment.word_ptr) != self.n_words + 1:
            raise ValueError(f"the segment has {len(segment.word_ptr) - 1} words, the index {self.n_words}")
        if not segment.live.all():
            raise ValueError("a base segment to load holds live documents only")
        self._base = segment
        ids = segment.ids
        self._base_order = None if bool(np.all(ids[1:] > ids[:-1])) else np.argsort(ids, kind="stable")
        self._base_keys = ids if self._base_order is None else ids[self._base_order]
        self._base_df = self._base.word_counts().astype(np.int64)
        self._dead = 0
        self._recent = RecentDocuments(self.n_words)

    def _base_row(self, doc_id: int) -> int | None:
        """The base row of live document ``doc_id`` (None when absent or removed).

        A binary search of the base's ids (the segment's array, memory-mapped and shared when the base comes from
        the machine's shared file: no per-process id -> row table). The base's ids are sorted whenever it was
        built by :meth:`compact` or from a database snapshot (``db/sbow.py``: ids sorted); any other order is
        searched through an argsort made at load.
        """
        keys, order = self._base_keys, self._base_order
        i = int(np.searchsorted(keys, doc_id))
        if i >= len(keys) or int(keys[i]) != doc_id:
            return None
        row = i if order is None else int(order[i])
        return row if bool(self._base.live[row]) else None

    def upsert(self, doc_id: int, words: np.ndarray, weights: np.ndarray, length: float) -> None:
        """Add or replace one document: its distinct ``words``, their ``weights`` and its word total ``length``.

        Words and weights as the postings rows of :func:`db.sbow.index_reference`.
        """
        words = np.asarray(words, np.int64).ravel()
        weights = np.asarray(weights, np.float64).ravel()
        if words.shape != weights.shape:
            raise ValueError("words and weights must have the same length")
        if len(np.unique(words)) != len(words):
            raise ValueError("words must be distinct (one postings row per word)")
        if len(words) and (words.min() < 0 or words.max() >= self.n_words):
            raise ValueError(f"word ids must lie in [0, {self.n_words})")
        self.remove(doc_id, missing_ok=True)
        order = np.argsort(words)
        self._recent.add(int(doc_id), words[order], weights[order], float(length))
        self._maybe_compact()

    def add_words(self, doc_id: int, words: np.ndarray) -> None:
        """Add or replace a document from its (N,) word array (one word per feature, repeats count).

        Its postings are its distinct words with their counts and its length the number of words, as
        :func:`db.sbow.index_reference` stores them.
        """
        distinct, counts = bag(words)
        self.upsert(doc_id, distinct, counts, float(counts.sum()))

    @classmethod
    def from_documents(cls, n_words: int, documents: Iterable[tuple[int, np.ndarray]]) -> SbowIndex:
        """An index over ``n_words`` words with the given (doc id, (N,) word array) documents."""
        index = cls(n_words)
        for doc_id, words in documents:
            index.add_words(doc_id, words)
        return index

    def remove(self, doc_id: int, *, missing_ok: bool = False) -> None:
        """Remove a document (KeyError when absent, unless ``missing_ok``)."""
        doc_id = int(doc_id)
        if self._recent.remove(doc_id):
            pass
        elif (row := self._base_row(doc_id)) is not None:
            self._base.live[row] = False
            self._base_df[self._base.words_of(row)] -= 1  # a document's words are distinct
            self._dead += 1
        elif not missing_ok:
            raise KeyError(doc_id)
        self._maybe_compact()

    def compact(self) -> None:
        """Merge the recent documents and drop removed ones: one base segment again."""
        base, recent = self._base, self._recent
        live_rows = np.flatnonzero(base.live)
        new_row = np.full(len(base.ids), -1, np.int32)
        new_row[live_rows] = np.arange(len(live_rows))
        keep = base.live[base.doc]
        base_word = np.repeat(np.arange(self.n_words, dtype=np.int32), base.word_counts())[keep]
        recent_ids, recent_lengths, recent_doc, recent_rows = recent.documents()
        ids = np.concatenate([base.ids[live_rows], recent_ids])
        lengths = np.concatenate([base.length[live_rows], recent_lengths])
        words = np.concatenate([base_word, recent.words[recent_rows]])
        docs = np.concatenate([new_row[base.doc[keep]], len(live_rows) + recent_doc]).astype(np.int32)
        weights = np.concatenate([base.weight[keep].astype(np.float64), recent.weights[recent_rows]])
        order = np.argsort(ids, kind="stable")  # documents by id: deterministic rows
        rank = np.empty(len(ids), np.int32)
        rank[order] = np.arange(len(ids))
        self.load(ids[order], lengths[order], words, rank[docs], weights)

    def _maybe_compact(self) -> None:
        n_base = len(self._base.ids)
        recent_full = self._recent.rows > max(COMPACT_MIN_RECENT, COMPACT_RECENT_SHARE * n_base)
        if recent_full or (self._dead > COMPACT_MIN_RECENT and self._dead > COMPACT_DEAD_SHARE * n_base):
            self.compact()

    # -- queries -----------------------------------------------------------------------------------

    def scores(self, query_words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ids, scores) of every document in the index for a query's (N,) words (one per feature), ids sorted."""
        base, recent, n_docs = self._base, self._recent, len(self)
        qw, qc = bag(query_words)
        if len(qw) and qw[0] < 0:
            raise ValueError("word ids must not be negative")
        base_scores = np.zeros(len(base.ids), np.float64)
        recent_scores = np.zeros(recent.rows, np.float64)
        if len(qw) and n_docs:
            # A word beyond the vocabulary has no postings: it counts in |q| and matches nothing (as in tfidf_scores).
            q_tf = (qc / qc.sum())[qw < self.n_words]
            qw = qw[qw < self.n_words]
            weights = idf(self._base_df[qw] + recent.df[qw], n_docs)
            _score_kernel(qw, weights, q_tf, base.word_ptr, base.doc, base.weight, base.length, base_scores)
            dense_tf, dense_idf = np.zeros(self.n_words), np.zeros(self.n_words)
            dense_tf[qw], dense_idf[qw] = q_tf, weights
            live = recent.live[: recent.rows]
            documents = (recent.ptr, recent.words, recent.weights, recent.length, live)
            _score_documents(dense_tf, dense_idf, documents, recent_scores)
        live = recent.live[: recent.rows]
        ids = np.concatenate([base.ids[base.live], recent.ids[: recent.rows][live]])
        scores = np.concatenate([base_scores[base.live], recent_scores[live]])
        order = np.argsort(ids, kind="stable")
        return ids[order], scores[order]

    def top(self, query_words: np.ndarray, n: int) -> list[tuple[int, float]]:
        """The ``n`` best documents as (id, score), best first (ties: lower id first); score 0 is left out.

        The same list as ranking :func:`geoloc.localize.retrieval.tfidf_scores` on the index's postings.
        """
        ids, values = self.scores(query_words)
        if n <= 0 or not len(ids):
            return []
        positive = np.flatnonzero(values > 0)
        if len(positive) > n:
            # Everything tied with the n-th best stays in: the tie-break by id decides among them.
            threshold = np.partition(values[positive], len(positive) - n)[len(positive) - n]
            positive = positive[values[positive] >= threshold]
        order = np.lexsort((ids[positive], -values[positive]))[:n]
        return [(int(ids[positive[i]]), float(values[positive[i]])) for i in order]


@numba.njit(cache=True, nogil=True)
def _score_documents(
    dense_tf: np.ndarray, dense_idf: np.ndarray, recent: tuple[np.ndarray, ...], out: np.ndarray
) -> None:  # pragma: no cover - compiled; checked against tfidf_scores in the tests
    """out[d] = sum over document d's words w (increasing) that the query has of idf_w * min(q_w, c_dw / |d|).

    recent: the recent documents' (ptr, words, weights, length, live) arrays (:class:`RecentDocuments`).
    """
    ptr, words, weights, length, live = recent
    for d in range(live.shape[0]):
        if not live[d]:
            continue
        total = 0.0
        for j in range(ptr[d], ptr[d + 1]):
            q = dense_tf[words[j]]
            if q > 0.0:
                total += dense_idf[words[j]] * min(q, weights[j] / max(length[d], 1.0))
        out[d] = total


@numba.njit(cache=True, nogil=True)
def _score_kernel(
    query_words: np.ndarray,
    idf_weights: np.ndarray,
    query_tf: np.ndarray,
    word_ptr: np.ndarray,
    doc: np.ndarray,
    weight: np.ndarray,
    length: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled; checked against tfidf_scores in the tests
    """out[d] += idf_w * min(q_w / |q|, c_dw / |d|) over the query's words w in increasing order."""
    for i in range(query_words.shape[0]):
        w = query_words[i]
        q = query_tf[i]
        f = idf_weights[i]
        for j in range(word_ptr[w], word_ptr[w + 1]):
            d = doc[j]
            d_tf = np.float64(weight[j]) / max(length[d], 1.0)
            out[d] += f * min(q, d_tf)
