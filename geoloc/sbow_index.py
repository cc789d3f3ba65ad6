"""An in-memory SBoW index for many references: word-major sparse postings scored by a compiled kernel.

The database's inverted index (``db/sbow.py``) is the source of truth; reading every posting of a query's
words from it costs time in the number of references (measured: 0.7 s at 10,000 references). This index
holds the same postings in memory, as a sparse matrix by word (CSR: for word w, the documents that have
it and their weights), and ranks exactly as :func:`geoloc.retrieval.tfidf_scores` does on the database's
postings: same formula, same float64 operations in the same order (each document's score sums its words in
increasing word id), the same document frequencies (live documents only) and the same ties (lower id
first). A test compares the two rankings.

Changes are incremental: :meth:`SbowIndex.upsert` and :meth:`SbowIndex.remove` touch a small *recent*
segment and a tombstone mask on the large *base* segment; when these grow past a share of the base, the
base is rebuilt from memory (:meth:`SbowIndex.compact`, a stable radix sort by word). The caller keeps
the index in step with the database (``workers/reference_store.py``: a change log read by a high-water
mark).

Memory: 4 bytes of document index and 4 (or 8) bytes of weight per posting (weights are stored as
float32 when that is exact, as the service's integer word counts are), plus per-document arrays: about
0.35 GB for 100,000 references of ~450 distinct words each (``benchmarks/bench_sbow.py``).
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

import numba
import numpy as np

from geoloc.retrieval import bag, idf

COMPACT_RECENT_SHARE = 0.05
"""The recent segment is merged into the base when it holds more than this share of the base's documents."""
COMPACT_MIN_RECENT = 2048
"""... and at least this many documents (small indexes live in the recent segment alone)."""
COMPACT_DEAD_SHARE = 0.2
"""The base is rebuilt when this share of its documents has been removed or replaced."""


@dataclass
class _Segment:
    """Documents as word-major postings: for word w, rows ``word_ptr[w]:word_ptr[w + 1]`` of ``doc``/``weight``
    (documents in increasing order within a word), and each document's words (``doc_ptr``, ``doc_word``).

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


class SbowIndex:
    """In-memory SBoW index over ``n_words`` visual words with integer document ids (reference ids).

    Scores and ranks as :func:`geoloc.retrieval.tfidf_scores` on the postings (module docstring). Not
    thread-safe: one per worker process (and map).
    """

    def __init__(self, n_words: int) -> None:
        self.n_words = int(n_words)
        self._base = _Segment.empty(self.n_words)
        self._base_row: dict[int, int] = {}
        self._base_df = np.zeros(self.n_words, np.int64)  # live postings per word in the base
        self._dead = 0
        self._recent: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}
        self._recent_segment: _Segment | None = None

    # -- contents ----------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._base_row) + len(self._recent)

    def __contains__(self, doc_id: Hashable) -> bool:
        return doc_id in self._base_row or doc_id in self._recent

    @property
    def doc_ids(self) -> np.ndarray:
        """Sorted ids of the documents in the index."""
        ids = np.concatenate([self._base.ids[self._base.live], np.fromiter(self._recent, np.int64, len(self._recent))])
        return np.sort(ids)

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays of the index (postings, documents, frequencies)."""
        recent = sum(w.nbytes + c.nbytes for w, c, _ in self._recent.values())
        compiled = self._recent_segment.nbytes if self._recent_segment is not None else 0
        return self._base.nbytes + self._base_df.nbytes + recent + compiled

    def postings(self, doc_id: int) -> tuple[np.ndarray, np.ndarray, float]:
        """A document's distinct words (sorted), their weights (float64) and its word total."""
        doc_id = int(doc_id)
        if doc_id in self._recent:
            words, weights, length = self._recent[doc_id]
            return words.copy(), weights.copy(), length
        row = self._base_row[doc_id]
        base = self._base
        words = np.sort(base.words_of(row))
        rows = np.array(
            [base.word_ptr[w] + np.searchsorted(base.doc[base.word_ptr[w] : base.word_ptr[w + 1]], row) for w in words],
            np.int64,
        )
        return words, base.weight[rows].astype(np.float64), float(base.length[row])

    def load(
        self,
        ids: np.ndarray,
        lengths: np.ndarray,
        post_word: np.ndarray,
        post_doc: np.ndarray,
        post_weight: np.ndarray,
    ) -> None:
        """Replace the contents with documents ``ids`` (word totals ``lengths``) and their postings rows
        (``post_doc`` indexes ``ids``); the bulk load of a map's whole index."""
        ids = np.asarray(ids, np.int64)
        if len(np.unique(ids)) != len(ids):
            raise ValueError("document ids must be distinct")
        self._base = _Segment.from_postings(self.n_words, ids, lengths, post_word, post_doc, post_weight)
        self._base_row = {int(d): i for i, d in enumerate(ids.tolist())}
        self._base_df = self._base.word_counts().astype(np.int64)
        self._dead = 0
        self._recent = {}
        self._recent_segment = None

    def upsert(self, doc_id: int, words: np.ndarray, weights: np.ndarray, length: float) -> None:
        """Add or replace one document: its distinct ``words`` and their ``weights`` (as the postings rows
        of :func:`db.sbow.index_reference`), and its word total ``length``."""
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
        self._recent[int(doc_id)] = (words[order], weights[order], float(length))
        self._recent_segment = None
        self._maybe_compact()

    def remove(self, doc_id: int, *, missing_ok: bool = False) -> None:
        """Remove a document (KeyError when absent, unless ``missing_ok``)."""
        doc_id = int(doc_id)
        if doc_id in self._recent:
            del self._recent[doc_id]
            self._recent_segment = None
        elif doc_id in self._base_row:
            row = self._base_row.pop(doc_id)
            self._base.live[row] = False
            self._base_df[self._base.words_of(row)] -= 1  # a document's words are distinct
            self._dead += 1
        elif not missing_ok:
            raise KeyError(doc_id)
        self._maybe_compact()

    def compact(self) -> None:
        """Merge the recent segment and drop removed documents: one base segment again."""
        base = self._base
        live_rows = np.flatnonzero(base.live)
        new_row = np.full(len(base.ids), -1, np.int32)
        new_row[live_rows] = np.arange(len(live_rows))
        keep = base.live[base.doc]
        base_word = np.repeat(np.arange(self.n_words, dtype=np.int32), base.word_counts())[keep]
        recent_ids = np.fromiter(self._recent, np.int64, len(self._recent))
        recent = [self._recent[int(i)] for i in recent_ids]
        sizes = np.array([len(w) for w, _, _ in recent], np.int64)
        ids = np.concatenate([base.ids[live_rows], recent_ids])
        lengths = np.concatenate([base.length[live_rows], np.array([n for _, _, n in recent], np.float64)])
        words = np.concatenate([base_word, *[w for w, _, _ in recent]]) if recent else base_word
        docs = np.concatenate(
            [new_row[base.doc[keep]], np.repeat(len(live_rows) + np.arange(len(recent)), sizes)]
        ).astype(np.int32)
        weights = np.concatenate([base.weight[keep].astype(np.float64), *[c for _, c, _ in recent]])
        order = np.argsort(ids, kind="stable")  # documents by id: deterministic rows
        rank = np.empty(len(ids), np.int32)
        rank[order] = np.arange(len(ids))
        self.load(ids[order], lengths[order], words, rank[docs], weights)

    def _maybe_compact(self) -> None:
        n_base = len(self._base.ids)
        recent_full = len(self._recent) > max(COMPACT_MIN_RECENT, COMPACT_RECENT_SHARE * n_base)
        if recent_full or (self._dead > COMPACT_MIN_RECENT and self._dead > COMPACT_DEAD_SHARE * n_base):
            self.compact()

    def _recent_compiled(self) -> _Segment:
        if self._recent_segment is None:
            ids = np.array(sorted(self._recent), np.int64)
            docs = [self._recent[int(i)] for i in ids]
            sizes = np.array([len(w) for w, _, _ in docs], np.int64)
            self._recent_segment = _Segment.from_postings(
                self.n_words,
                ids,
                np.array([n for _, _, n in docs], np.float64),
                np.concatenate([w for w, _, _ in docs]) if docs else np.zeros(0, np.int64),
                np.repeat(np.arange(len(docs)), sizes),
                np.concatenate([c for _, c, _ in docs]) if docs else np.zeros(0),
            )
        return self._recent_segment

    # -- queries -----------------------------------------------------------------------------------

    def scores(self, query_words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ids, scores) of every document in the index for a query's (N,) words (one per feature), ids sorted."""
        recent = self._recent_compiled()
        base, n_docs = self._base, len(self)
        qw, qc = bag(query_words)
        if len(qw) and (qw[0] < 0 or qw[-1] >= self.n_words):
            raise ValueError(f"word ids must lie in [0, {self.n_words})")
        values = [np.zeros(len(base.ids), np.float64), np.zeros(len(recent.ids), np.float64)]
        if len(qw) and n_docs:
            weights = idf(self._base_df[qw] + recent.word_counts()[qw], n_docs)
            q_tf = qc / qc.sum()
            for segment, out in zip((base, recent), values, strict=True):
                _score_kernel(qw, weights, q_tf, segment.word_ptr, segment.doc, segment.weight, segment.length, out)
        ids = np.concatenate([base.ids[base.live], recent.ids])
        scores = np.concatenate([values[0][base.live], values[1]])
        order = np.argsort(ids, kind="stable")
        return ids[order], scores[order]

    def top(self, query_words: np.ndarray, n: int) -> list[tuple[int, float]]:
        """The ``n`` best documents as (id, score), best first (ties: lower id first); score 0 is left out.

        The same list as ranking :func:`geoloc.retrieval.tfidf_scores` on the index's postings.
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
