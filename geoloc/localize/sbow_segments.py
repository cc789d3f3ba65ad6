"""The storage of :class:`geoloc.localize.sbow_index.SbowIndex`: a word-major base segment and recent documents.

:class:`Segment`: documents as word-major sparse postings (CSR by word) with each document's words, built
from postings rows in any order by counting sorts (linear time). :class:`RecentDocuments`: documents added
since the base was built, document-major and appendable. Both hold weights as float64 or, where exact,
float32 (integer word counts are).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@dataclass
class Segment:
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
    def empty(cls, n_words: int) -> Segment:
        """A segment without documents over ``n_words`` words."""
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
    ) -> Segment:
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

    ARRAY_NAMES = ("ids", "length", "live", "word_ptr", "doc", "weight", "doc_ptr", "doc_word")
    """The segment's arrays, as :meth:`arrays` names them."""

    def arrays(self) -> dict[str, np.ndarray]:
        """The segment as named arrays (to be written to a file and read back by :meth:`from_arrays`)."""
        return {name: getattr(self, name) for name in self.ARRAY_NAMES}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> Segment:
        """A segment from :meth:`arrays` output, used as it is (read-only memory-mapped arrays stay shared).

        Only ``live`` is copied: removing a document writes to it, and that is the process's own business.
        """
        values = {name: arrays[name] for name in cls.ARRAY_NAMES}
        values["live"] = np.array(values["live"], dtype=bool)
        return cls(**values)

    def words_of(self, row: int) -> np.ndarray:
        """The distinct words of document ``row`` (int64, in no particular order)."""
        return self.doc_word[self.doc_ptr[row] : self.doc_ptr[row + 1]].astype(np.int64)

    def word_counts(self) -> np.ndarray:
        """(V,) number of postings of each word (live or not)."""
        return np.diff(self.word_ptr)

    @property
    def nbytes(self) -> int:
        """Bytes held by the segment's arrays."""
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


class RecentDocuments:
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
        """Number of live documents."""
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
        """Bytes held by the store's arrays."""
        arrays = (self.ids, self.length, self.live, self.ptr, self.words, self.weights, self.df)
        return int(sum(a.nbytes for a in arrays))


def _grown(array: np.ndarray, needed: int) -> np.ndarray:
    """``array`` in a buffer of at least twice ``needed`` elements (contents kept)."""
    out = np.zeros(max(2 * needed, 16), array.dtype)
    out[: len(array)] = array
    return out
