"""The machine's shared SBoW base segment: the same shortlists as a process's own index, to the last bit.

A "second process" is this one with its in-memory indexes dropped (what a fresh worker starts from).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from db import Database, connect, migrate, sbow, transaction
from db import references as reference_store
from geoloc.core.array_file import is_mapped, map_arrays
from geoloc.localize.retrieval import Vocabulary
from tests.conftest import Profile
from tests.unit.db.test_db import add_reference
from tests.unit.workers.test_reference_store import _reference, _store_references
from workers import reference_store as store_module
from workers import sbow_share
from workers.reference_store import DatabaseReferenceStore


def _queries(vocabulary: Vocabulary, count: int = 12) -> list[np.ndarray]:
    rng = np.random.default_rng(11)
    photos = [_reference(rng, 0, n=int(rng.integers(10, 80))) for _ in range(count)]
    return [vocabulary.words(photo.features.descriptors) for photo in photos]


def _answers(store: DatabaseReferenceStore, queries: list[np.ndarray]) -> list[list[tuple[object, float]]]:
    store_module._INDEXES.clear()  # a fresh worker process
    return [store.shortlist(words, 8) for words in queries]


def _add(db: Database, map_id: int, vocabulary: Vocabulary, first: int, count: int) -> None:
    rng = np.random.default_rng(first)
    for i in range(first, first + count):
        reference_id = add_reference(db, map_id, f"{i:064d}")
        words = vocabulary.words(_reference(rng, reference_id, n=40).features.descriptors)
        with transaction(db):
            sbow.index_reference(db, map_id, reference_id, words, np.ones(len(words)))


def test_a_shared_base_answers_as_the_process_own_index(tmp_path: Path, profile: Profile) -> None:
    target, _ = profile.new_deployment(tmp_path)
    db = connect(target)
    map_id, vocabulary, _ = _store_references(db, count=40)
    queries = _queries(vocabulary)
    shared_dir = tmp_path / "sbow"
    own, shared = DatabaseReferenceStore(db, map_id), DatabaseReferenceStore(db, map_id, shared_dir=shared_dir)
    before = _answers(own, queries)
    assert all(before) and _answers(shared, queries) == before  # same ids, same float scores
    files = list(shared_dir.glob("*.sbow.npz"))
    assert len(files) == 1
    live = shared.live_index()
    assert live is not None and is_mapped(live.index._base.doc) and is_mapped(live.index._base.weight)
    mark = int(map_arrays(files[0])["mark"][0])

    # Changes after the file was written: a new process maps the same file and reads the rest from the log.
    _add(db, map_id, vocabulary, 1000, 6)
    removed = before[0][0][0]
    with transaction(db):
        reference_store.delete_reference(db, int(removed))  # type: ignore[call-overload]
    after = _answers(own, queries)
    assert after != before and all(removed not in [r for r, _ in top] for top in after)
    assert _answers(shared, queries) == after
    assert int(map_arrays(files[0])["mark"][0]) == mark  # not rewritten for a few changes
    db.close()


def test_the_file_is_rewritten_when_the_log_has_moved_far_or_it_is_damaged(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    db = connect(tmp_path / "geoloc.sqlite3")
    migrate(db)
    map_id, vocabulary, _ = _store_references(db, count=10)
    queries = _queries(vocabulary, 6)
    shared_dir = tmp_path / "sbow"
    shared = DatabaseReferenceStore(db, map_id, shared_dir=shared_dir)
    _answers(shared, queries)
    (path,) = shared_dir.glob("*.sbow.npz")
    first_mark = int(map_arrays(path)["mark"][0])
    monkeypatch.setattr(sbow_share, "REBUILD_AFTER_CHANGES", 2)
    _add(db, map_id, vocabulary, 2000, 3)
    answers = _answers(shared, queries)
    assert int(map_arrays(path)["mark"][0]) > first_mark == int(map_arrays(path)["mark"][0]) - 3
    path.write_bytes(b"damaged")
    assert _answers(shared, queries) == answers == _answers(DatabaseReferenceStore(db, map_id), queries)
    assert int(map_arrays(path)["mark"][0]) == first_mark + 3
    db.close()


def test_deleting_the_map_removes_its_shared_base(tmp_path: Path, profile: Profile) -> None:
    from contracts.settings import Settings
    from db.files import open_store
    from service.routes_maps import _delete_map
    from workers.sbow_files import sbow_cache_dir

    settings = Settings(data_dir=tmp_path / "data")
    target, _ = profile.new_deployment(settings.data_dir)
    db = connect(target)
    kept_map, _, _ = _store_references(db, seed=1, count=10)
    map_id, _, _ = _store_references(db, count=10)
    for each in (kept_map, map_id):  # each map's index read once, as a worker's first query does: files written
        assert DatabaseReferenceStore(db, each, shared_dir=sbow_cache_dir(settings.data_dir)).live_index()
    files = {path.name for path in sbow_cache_dir(settings.data_dir).glob(f"map{map_id}-*")}
    assert len(files) == 2  # the base segment and its lock file
    assert _delete_map(settings, open_store(settings.file_store_dir), map_id, db)
    left = {path.name for path in sbow_cache_dir(settings.data_dir).iterdir()}
    assert not left & files
    assert any(name.startswith(f"map{kept_map}-") and name.endswith(".sbow.npz") for name in left)
