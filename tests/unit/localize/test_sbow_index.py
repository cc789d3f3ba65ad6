"""The in-memory SBoW index ranks as tfidf_scores on the database's postings, and follows the database."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from db import Database, connect, migrate, sbow, transaction
from db import maps as map_store
from db import references as reference_store
from geoloc.core.array_file import is_mapped, map_arrays, write_arrays
from geoloc.localize.retrieval import bag, tfidf_scores
from geoloc.localize.sbow_index import SbowIndex
from geoloc.localize.sbow_segments import Segment
from tests.unit.db.test_db import add_map, add_reference
from workers import reference_store as store_module
from workers.reference_store import DatabaseReferenceStore

N_WORDS = 512


def _zipf_words(rng: np.random.Generator, n: int) -> np.ndarray:
    p = 1.0 / np.arange(1, N_WORDS + 1) ** 0.8
    return rng.choice(N_WORDS, size=n, p=p / p.sum())


def _reference_ranking(docs: dict[int, np.ndarray], query: np.ndarray, n: int) -> list[tuple[int, float]]:
    """tfidf_scores on every postings row, documents in id order, ties to the lower id (the SQL path)."""
    ids = sorted(docs)
    bags = [bag(docs[i]) for i in ids]
    word = np.concatenate([w for w, _ in bags])
    doc = np.repeat(np.arange(len(ids)), [len(w) for w, _ in bags])
    count = np.concatenate([c for _, c in bags]).astype(float)
    lengths = np.array([len(docs[i]) for i in ids], float)
    scores = tfidf_scores(query, word, doc, count, lengths, len(ids))
    order = np.argsort(-scores, kind="stable")[:n]
    return [(ids[i], float(scores[i])) for i in order if scores[i] > 0]


def _upsert(index: SbowIndex, doc_id: int, words: np.ndarray) -> None:
    distinct, counts = bag(words)
    index.upsert(doc_id, distinct, counts, float(len(words)))


def test_ranking_equals_tfidf_scores_through_changes(monkeypatch: pytest.MonkeyPatch) -> None:
    # Compact often, so base, recent segment and tombstones all take part.
    monkeypatch.setattr("geoloc.localize.sbow_index.COMPACT_MIN_RECENT", 40)
    rng = np.random.default_rng(0)
    docs = {int(i): _zipf_words(rng, int(rng.integers(0, 300))) for i in rng.choice(5000, 400, replace=False)}
    docs[min(docs) - 1] = np.zeros(0, np.int64)  # a reference without features is a document too
    index = SbowIndex(N_WORDS)
    ids = np.array(sorted(docs))
    bags = [bag(docs[int(i)]) for i in ids]
    index.load(
        ids,
        np.array([len(docs[int(i)]) for i in ids], float),
        np.concatenate([w for w, _ in bags]),
        np.repeat(np.arange(len(ids)), [len(w) for w, _ in bags]),
        np.concatenate([c for _, c in bags]),
    )

    def check() -> None:
        assert len(index) == len(docs) and index.doc_ids.tolist() == sorted(docs)
        for _ in range(10):
            query = _zipf_words(rng, int(rng.integers(50, 400)))
            got, expected = index.top(query, 10), _reference_ranking(docs, query, 10)
            assert got == expected  # same ids, same order, bit-identical scores

    check()
    for step in range(300):
        action = rng.random()
        if action < 0.5:  # a new reference
            doc_id = int(rng.integers(5000, 10_000))
            docs[doc_id] = _zipf_words(rng, int(rng.integers(1, 300)))
            _upsert(index, doc_id, docs[doc_id])
        elif action < 0.75:  # re-labelled: its postings are replaced
            doc_id = int(rng.choice(sorted(docs)))
            docs[doc_id] = _zipf_words(rng, int(rng.integers(1, 300)))
            _upsert(index, doc_id, docs[doc_id])
        else:
            doc_id = int(rng.choice(sorted(docs)))
            del docs[doc_id]
            index.remove(doc_id)
        if step % 60 == 0:
            check()
    check()
    index.compact()
    check()
    some = sorted(docs)[3]
    words, weights, length = index.postings(some)
    expected_words, expected_counts = bag(docs[some])
    assert words.tolist() == expected_words.tolist() and weights.tolist() == expected_counts.tolist()
    assert length == len(docs[some])


def test_ties_go_to_the_lower_id() -> None:
    index = SbowIndex(16)
    for doc_id in (30, 10, 20):
        index.upsert(doc_id, np.array([1, 2]), np.array([1.0, 1.0]), 2.0)
    index.upsert(5, np.array([3]), np.array([1.0]), 1.0)
    assert [d for d, _ in index.top(np.array([1, 2]), 2)] == [10, 20]
    assert index.top(np.array([9]), 5) == []  # no shared word, no result
    assert index.top(np.array([16, 17]), 5) == []  # beyond the vocabulary: no postings
    # ... but such words count in the query's length, as tfidf_scores counts them
    assert index.top(np.array([3, 16]), 1)[0][1] == pytest.approx(np.log1p(4 / 1) * 0.5)
    with pytest.raises(ValueError, match="negative"):
        index.top(np.array([-1]), 5)
    with pytest.raises(KeyError):
        index.remove(99)


def _add_indexed_reference(db: Database, map_id: int, number: int, words: np.ndarray) -> int:
    reference_id = add_reference(db, map_id, f"{number:064d}")
    with transaction(db):
        sbow.index_reference(db, map_id, reference_id, words, np.ones(len(words)))
    return reference_id


def _sql_ranking(db: Database, map_id: int, query: np.ndarray, n: int) -> list[tuple[int, float]]:
    """The ranking the service computed before the in-memory index: every postings row of the query's words."""
    p = sbow.postings_for_words(db, map_id, query)
    scores = tfidf_scores(query, p.word, p.doc, p.count, p.doc_lengths, p.n_docs)
    order = np.argsort(-scores, kind="stable")[:n]
    return [(int(p.reference_ids[i]), float(scores[i])) for i in order if scores[i] > 0]


def test_database_store_follows_the_database(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    path = tmp_path / "geoloc.sqlite3"
    worker_db, writer_db = connect(path), connect(path)  # the worker reads; the API and other workers write
    migrate(worker_db)
    map_id = add_map(writer_db)
    with transaction(writer_db):
        sbow.save_vocabulary(writer_db, map_id, {"centers": np.zeros((N_WORDS, 4), np.float32)})
    refs = [_add_indexed_reference(writer_db, map_id, i, _zipf_words(rng, 200)) for i in range(30)]
    store = DatabaseReferenceStore(worker_db, map_id)
    queries = [_zipf_words(rng, 250) for _ in range(5)]

    def check() -> None:
        for query in queries:
            assert store.shortlist(query, 8) == _sql_ranking(worker_db, map_id, query, 8)

    check()
    live = store.live_index()
    assert live is not None and live.mark == sbow.change_mark(worker_db, map_id) and len(live.index) == 30
    # Another connection adds, re-indexes and deletes references: the next shortlist sees all of it.
    refs.append(_add_indexed_reference(writer_db, map_id, 100, queries[0]))  # the best match of query 0
    with transaction(writer_db):
        sbow.index_reference(writer_db, map_id, refs[0], queries[1], np.ones(len(queries[1])))
    with transaction(writer_db):
        reference_store.delete_reference(writer_db, refs[5])
    check()
    assert store.shortlist(queries[0], 1)[0][0] == refs[-1]
    assert store.shortlist(queries[1], 1)[0][0] == refs[0]
    assert refs[5] not in [r for r, _ in store.shortlist(queries[2], 40)]
    # A write that is rolled back changes nothing.
    with pytest.raises(RuntimeError), transaction(writer_db):
        sbow.index_reference(writer_db, map_id, refs[1], queries[2], np.ones(len(queries[2])))
        raise RuntimeError("crash mid-way")
    check()
    # A fresh process (empty cache) reads the same index from scratch.
    store_module._INDEXES.clear()
    check()
    with transaction(writer_db):
        map_store.delete_map(writer_db, map_id)
    assert store.shortlist(queries[0], 8) == []
    worker_db.close()
    writer_db.close()


@pytest.mark.parametrize("id_order", ["sorted", "shuffled"])
def test_a_memory_mapped_base_takes_removals_and_upserts(tmp_path: Path, id_order: str) -> None:
    """The base's id -> row lookup is a search of its (mapped, read-only) ids: changes still rank as tfidf_scores."""
    rng = np.random.default_rng(3)
    docs = {int(i): _zipf_words(rng, int(rng.integers(1, 200))) for i in rng.choice(3000, 120, replace=False)}
    ids = np.array(sorted(docs)) if id_order == "sorted" else rng.permutation(np.array(list(docs)))
    bags = [bag(docs[int(i)]) for i in ids]
    built = SbowIndex(N_WORDS)
    built.load(
        ids,
        np.array([len(docs[int(i)]) for i in ids], float),
        np.concatenate([w for w, _ in bags]),
        np.repeat(np.arange(len(ids)), [len(w) for w, _ in bags]),
        np.concatenate([c for _, c in bags]),
    )
    write_arrays(tmp_path / "base.npz", built._base.arrays())
    mapped = map_arrays(tmp_path / "base.npz")
    assert is_mapped(mapped["ids"]) and not mapped["ids"].flags.writeable
    index = SbowIndex(N_WORDS)
    index.load_segment(Segment.from_arrays(mapped))
    assert len(index) == len(docs) and all(i in index for i in docs)
    assert max(docs) + 1 not in index and min(docs) - 1 not in index and "x" not in index
    words, weights, length = index.postings(int(ids[5]))
    assert np.array_equal(words, bag(docs[int(ids[5])])[0]) and length == len(docs[int(ids[5])])
    gone, replaced = [int(i) for i in ids[:10]], [int(i) for i in ids[10:20]]
    for doc_id in gone:
        index.remove(doc_id)
        del docs[doc_id]
    for doc_id in replaced:
        docs[doc_id] = _zipf_words(rng, 50)
        _upsert(index, doc_id, docs[doc_id])
    new_id = max(docs) + 7
    docs[new_id] = _zipf_words(rng, 80)
    _upsert(index, new_id, docs[new_id])
    assert len(index) == len(docs) and all(i not in index for i in gone) and new_id in index
    assert np.array_equal(index.doc_ids, np.array(sorted(docs)))
    with pytest.raises(KeyError):
        index.remove(gone[0])
    with pytest.raises(KeyError):
        index.postings(gone[0])
    assert np.array_equal(index.postings(replaced[0])[0], bag(docs[replaced[0]])[0])
    for _ in range(8):
        query = _zipf_words(rng, 150)
        assert index.top(query, 10) == _reference_ranking(docs, query, 10)
    index.compact()
    query = _zipf_words(rng, 150)
    assert len(index) == len(docs) and index.top(query, 10) == _reference_ranking(docs, query, 10)
