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
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

import numba
import numpy as np

from geoloc.localize.retrieval import bag, idf

COMPACT_RECENT_SHARE = 0.05
"""The recent segment is merged into the base when it holds more than this share of the base's documents."""
COMPACT_MIN_RECENT = 2048
"""... and at least this many documents (small indexes live in the recent segment alone)."""
COMPACT_DEAD_SHARE = 0.2
"""The base is rebuilt when this share of its documents has been removed or replaced."""


@dataclass
class _Segment:
    """Documents as word-major postings, and each document's words (``doc_ptr``, ``doc_word``).

    For word w, rows ``word_ptr[w]:word_ptr[w + 1]`` of ``doc``/``weight`` (documents in increasing order
    within a word).

    ids: (D,) int64 document ids; length: (D,) float64 word totals; live: (D,) bool (False: removed);
    doc: (P,) int32 indices into ``ids``; weight: (P,) float32 or float64 term weights;
    doc_word: (P,) the words of document d at ``doc_ptr[d]:doc_ptr[d + 1]`` (to forget a removed document).
    """

    ids: np.ndarray
    length: np.ndarray
    live: np.ndarray
    word_ptr: np.ndarray
    doc: np.ndarray
    weight: np.ndarray
    doc_ptr: np.ndarray
    doc_word: np.ndarray

    @classmethod
    def empty(cls, n_words: int) -> _Segment:
        return cls.from_postings(
            n_words, np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        )

    @classmethod
    def from_postings(
        cls,
        n_words: int,
        ids: np.ndarray,
        length: np.ndarray,
        word: np.ndarray,
        doc: np.ndarray,
        weight: np.ndarray,
    ) -> _Segment:
        """A segment from postings rows in any order (``doc`` indexes ``ids``), sorted by word, then document.

        Rows already in that order (a database's primary-key order) are kept as they are: no copy.
        """
        word = np.asarray(word)
        doc = np.asarray(doc)
        if len(word) and (word.min() < 0 or word.max() >= n_words):
            raise ValueError(f"word ids must lie in [0, {n_words})")
        if len(doc) and (doc.min() < 0 or doc.max() >= len(ids)):
            raise ValueError("postings must refer to the documents given")
        word_type = np.uint16 if n_words <= 1 << 16 else np.int32
        by_doc, doc_ptr = _counting_sort(doc, len(ids))
        doc_word = word[by_doc].astype(word_type)
        if _sorted_by_word_then_doc(word, doc):
            word_ptr = np.concatenate([[0], np.cumsum(np.bincount(word, minlength=n_words))]).astype(np.int64)
            ordered_doc, ordered_weight = doc, np.asarray(weight)
        else:
            by_word, word_ptr = _counting_sort(doc_word, n_words)  # stable: documents stay in order
            order = by_doc[by_word]
            del by_word
            ordered_doc, ordered_weight = doc[order], np.asarray(weight)[order]
        del by_doc
        return cls(
            np.asarray(ids, np.int64),
            np.asarray(length, np.float64),
            np.ones(len(ids), bool),
            word_ptr,
            np.asarray(ordered_doc, np.int32),
            _compact_weights(ordered_weight),
            doc_ptr,
            doc_word,
        )

    def words_of(self, row: int) -> np.ndarray:
        """The distinct words of document ``row`` (int64, in no particular order)."""
        return self.doc_word[self.doc_ptr[row] : self.doc_ptr[row + 1]].astype(np.int64)

    def word_counts(self) -> np.ndarray:
        """(V,) number of postings of each word (live or not)."""
        return np.diff(self.word_ptr)

    @property
    def nbytes(self) -> int:
        arrays = (self.ids, self.length, self.live, self.word_ptr, self.doc, self.weight, self.doc_ptr, self.doc_word)
        return int(sum(a.nbytes for a in arrays))


@numba.njit(cache=True, nogil=True)
def _counting_sort_kernel(keys: np.ndarray, counts: np.ndarray, order: np.ndarray) -> None:  # pragma: no cover
    for key in keys:
        counts[key + 1] += 1
    for k in range(len(counts) - 1):
        counts[k + 1] += counts[k]
    starts = counts[:-1].copy()
    for i in range(len(keys)):
        key = keys[i]
        order[starts[key]] = i
        starts[key] += 1


def _counting_sort(keys: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """Stable order of integer ``keys`` in [0, n_keys) and the (n_keys + 1,) start of each key's run: O(N)."""
    keys = np.asarray(keys)
    counts = np.zeros(int(n_keys) + 1, np.int64)
    order = np.empty(len(keys), np.int32 if len(keys) < 2**31 else np.int64)
    _counting_sort_kernel(keys, counts, order)
    return order, counts


@numba.njit(cache=True, nogil=True)
def _sorted_by_word_then_doc(word: np.ndarray, doc: np.ndarray) -> bool:  # pragma: no cover
    for i in range(1, len(word)):
        if word[i] < word[i - 1] or (word[i] == word[i - 1] and doc[i] <= doc[i - 1]):
            return False
    return True


def _compact_weights(weight: np.ndarray) -> np.ndarray:
    """float32 when every weight is exactly a float32 (integer word counts are), else float64."""
    if weight.dtype == np.float32:
        return weight
    weight = np.asarray(weight, np.float64)
    single = weight.astype(np.float32)
    return single if np.array_equal(single, weight) else weight


class _Recent:
    """Documents added since the base was built, document-major and appendable (arrays grow by doubling).

    Row r holds words ``words[ptr[r]:ptr[r + 1]]`` (sorted) with their weights, ``length[r]``, ``ids[r]``;
    a replaced or removed document's row stays, marked dead, until the next compaction. ``df``: live
    documents per word.
    """

    def __init__(self, n_words: int) -> None:
        self.row_of: dict[int, int] = {}
        self.rows = 0
        self.ids = np.zeros(16, np.int64)
        self.length = np.zeros(16, np.float64)
        self.live = np.zeros(16, bool)
        self.ptr = np.zeros(17, np.int64)
        self.words = np.zeros(1024, np.int32)
        self.weights = np.zeros(1024, np.float64)
        self.df = np.zeros(n_words, np.int64)

    def __len__(self) -> int:
        return len(self.row_of)

    def add(self, doc_id: int, words: np.ndarray, weights: np.ndarray, length: float) -> None:
        """Append a document (``words`` distinct and sorted); the caller removed any earlier one."""
        r, start = self.rows, int(self.ptr[self.rows])
        if r + 1 >= len(self.ids):
            self.ids, self.length, self.live = (_grown(a, r + 2) for a in (self.ids, self.length, self.live))
            self.ptr = _grown(self.ptr, r + 3)
        if start + len(words) > len(self.words):
            self.words, self.weights = (_grown(a, start + len(words)) for a in (self.words, self.weights))
        self.ids[r], self.length[r], self.live[r] = doc_id, length, True
        self.words[start : start + len(words)] = words
        self.weights[start : start + len(words)] = weights
        self.ptr[r + 1] = start + len(words)
        self.df[words] += 1
        self.row_of[doc_id] = r
        self.rows += 1

    def remove(self, doc_id: int) -> bool:
        """Mark a document dead; False when it is not here."""
        r = self.row_of.pop(doc_id, None)
        if r is None:
            return False
        self.live[r] = False
        self.df[self.words[self.ptr[r] : self.ptr[r + 1]]] -= 1
        return True

    def documents(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ids, lengths, words, weights) of the live documents, one row per (document, word)."""
        rows = np.flatnonzero(self.live[: self.rows])
        sizes = self.ptr[rows + 1] - self.ptr[rows]
        index = np.repeat(self.ptr[rows] - np.cumsum(sizes) + sizes, sizes) + np.arange(int(sizes.sum()))
        return self.ids[rows], self.length[rows], np.repeat(np.arange(len(rows)), sizes), index

    @property
    def nbytes(self) -> int:
        arrays = (self.ids, self.length, self.live, self.ptr, self.words, self.weights, self.df)
        return int(sum(a.nbytes for a in arrays))


def _grown(array: np.ndarray, needed: int) -> np.ndarray:
    """``array`` in a buffer of at least twice ``needed`` elements (contents kept)."""
    out = np.zeros(max(2 * needed, 16), array.dtype)
    out[: len(array)] = array
    return out


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
        self._base = _Segment.empty(self.n_words)
        self._base_row: dict[int, int] = {}
        self._base_df = np.zeros(self.n_words, np.int64)  # live postings per word in the base
        self._dead = 0
        self._recent = _Recent(self.n_words)

    # -- contents ----------------------------------------------------------------------------------

    def __len__(self) -> int:
        """Number of live documents."""
        return len(self._base_row) + len(self._recent)

    def __contains__(self, doc_id: Hashable) -> bool:
        """Whether ``doc_id`` is a live document."""
        return doc_id in self._base_row or doc_id in self._recent.row_of

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
        row = self._base_row[doc_id]
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
        self._base = _Segment.from_postings(self.n_words, ids, lengths, post_word, post_doc, post_weight)
        self._base_row = {int(d): i for i, d in enumerate(ids.tolist())}
        self._base_df = self._base.word_counts().astype(np.int64)
        self._dead = 0
        self._recent = _Recent(self.n_words)

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

    def remove(self, doc_id: int, *, missing_ok: bool = False) -> None:
        """Remove a document (KeyError when absent, unless ``missing_ok``)."""
        doc_id = int(doc_id)
        if self._recent.remove(doc_id):
            pass
        elif doc_id in self._base_row:
            row = self._base_row.pop(doc_id)
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
            _score_documents(
                dense_tf, dense_idf, recent.ptr, recent.words, recent.weights, recent.length, live, recent_scores
            )
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
    dense_tf: np.ndarray,
    dense_idf: np.ndarray,
    ptr: np.ndarray,
    words: np.ndarray,
    weights: np.ndarray,
    length: np.ndarray,
    live: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled; checked against tfidf_scores in the tests
    """out[d] = sum over document d's words w (increasing) that the query has of idf_w * min(q_w, c_dw / |d|)."""
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
