"""The query stage sees the same references from the database (either engine) as from memory.

SBoW retrieval ranks alike on SQLite and PostgreSQL.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from contracts.references import UNKNOWN_POSITION_SIGMA_M, ReferenceKeypoints
from db import Database, connect, migrate, sbow, transaction
from db import references as reference_store
from db.blobs import pack_arrays, unpack_arrays
from geoloc.evaluation.store import InMemoryReferenceStore
from geoloc.localize.anchors import MapAnchors
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.store import StoredReference
from geoloc.vision.features import Features
from testbed.servers import PostgresServer
from tests.conftest import Profile
from tests.unit.db.test_db import add_map, add_reference
from workers.reference_store import DatabaseReferenceStore


def _reference(rng: np.random.Generator, reference_id: int, n: int = 50) -> StoredReference:
    descriptors = rng.random((n, 128)).astype(np.float32)
    descriptors /= np.linalg.norm(descriptors, axis=1, keepdims=True)
    features = Features(rng.random((n, 2)) * 600, descriptors, np.ones(n), np.zeros(n), np.ones(n), (480, 640))
    anchors = MapAnchors(rng.random((n, 3)) * 20, rng.integers(-1, 30, n), rng.integers(-1, 5, n), rng.random(n) * 30)
    identity = rng.random((n, 2)).astype(np.float32)
    position = rng.random(2) * 100
    return StoredReference(reference_id, features, identity, np.array([3, 4]), anchors, np.diag([4.0, 9.0]), position)


def _store_references(db: Database, seed: int = 0, count: int = 25) -> tuple[int, Vocabulary, InMemoryReferenceStore]:
    """Store and index ``count`` random references of a new map in ``db``; the same ones for the same seed.

    Returns the map id, the vocabulary and the same references in memory.
    """
    rng = np.random.default_rng(seed)
    map_id = add_map(db)
    # A small vocabulary, so that references share words and ranks depend on counts and idf.
    vocabulary = Vocabulary(rng.random((40, 128)).astype(np.float32))
    memory = InMemoryReferenceStore(vocabulary)
    for i in range(count):
        reference_id = add_reference(db, map_id, f"{i:064d}")
        ref = _reference(rng, reference_id, n=int(rng.integers(20, 80)))
        words = vocabulary.words(ref.features.descriptors)
        with transaction(db):
            reference_store.save_keypoints(db, reference_id, ref.keypoints())
            sbow.index_reference(db, map_id, reference_id, words, np.ones(len(words)))
        memory.add(ref)
    return map_id, vocabulary, memory


def test_database_and_memory_stores_rank_and_load_alike(tmp_path: Path, profile: Profile) -> None:
    rng = np.random.default_rng(1)
    target, _ = profile.new_deployment(tmp_path)
    db = connect(target)
    map_id, vocabulary, memory = _store_references(db)
    database = DatabaseReferenceStore(db, map_id)
    for _ in range(10):
        query_words = vocabulary.words(_reference(rng, 0, n=60).features.descriptors)
        from_db, from_memory = database.shortlist(query_words, 8), memory.shortlist(query_words, 8)
        assert [r for r, _ in from_db] == [r for r, _ in from_memory]
        assert np.allclose([s for _, s in from_db], [s for _, s in from_memory])
    loaded = database.load([from_db[0][0], 999_999])
    assert list(loaded) == [from_db[0][0]]  # an unknown id is left out
    stored, kept = loaded[from_db[0][0]], memory.references[from_db[0][0]]
    # The memory store keeps what the database gives back, to the bit (float16 descriptors, float32 anchors),
    # so the evaluation's answers are the service's.
    for name in ("xy", "descriptors", "sizes", "angles", "responses"):
        a, b = getattr(stored.features, name), getattr(kept.features, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert stored.features.descriptors.dtype == np.float32
    for name in ("xyz", "facade_id", "building_id", "distance_m"):
        a, b = getattr(stored.anchors, name), getattr(kept.anchors, name)
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), name
    assert np.array_equal(stored.keypoint_prob, kept.keypoint_prob)
    assert np.array_equal(stored.building_ids, kept.building_ids)
    assert np.array_equal(stored.position_covariance, kept.position_covariance)
    assert np.array_equal(stored.position_xy, kept.position_xy)
    db.close()


def test_sbow_top_k_is_the_same_on_both_engines(tmp_path: Path, postgres_server: PostgresServer) -> None:
    """The same references stored in SQLite and in PostgreSQL: every query gets the same top-k, same scores."""
    embedded, distributed = connect(tmp_path / "geoloc.sqlite3"), connect(postgres_server.new_database())
    migrate(embedded)
    (map_a, vocabulary, _), (map_b, _, _) = (
        _store_references(embedded, count=40),
        _store_references(distributed, count=40),
    )
    rng = np.random.default_rng(7)
    for k in (1, 4, 8, 20):
        for _ in range(10):
            words = vocabulary.words(_reference(rng, 0, n=int(rng.integers(10, 80))).features.descriptors)
            top_a = DatabaseReferenceStore(embedded, map_a).shortlist(words, k)
            top_b = DatabaseReferenceStore(distributed, map_b).shortlist(words, k)
            assert top_a and [r for r, _ in top_a] == [r for r, _ in top_b]
            assert [s for _, s in top_a] == pytest.approx([s for _, s in top_b], rel=1e-12)
    embedded.close()
    distributed.close()


def test_positions_and_vocabulary_follow_the_database(tmp_path: Path) -> None:
    # Both are kept decoded per process; a re-labelled reference or a replaced vocabulary is read again.
    from workers.handler_helpers import vocabulary_for

    db = connect(tmp_path / "geoloc.sqlite3")
    migrate(db)
    map_id, vocabulary, memory = _store_references(db, count=5)
    store = DatabaseReferenceStore(db, map_id)
    ids = sorted(memory.references)
    first = store.positions([*ids, 999_999])
    assert list(first) == ids  # an unknown id is left out
    assert all(np.array_equal(first[i], memory.references[i].position_xy) for i in ids)
    moved = np.array([-12.5, 40.0])
    keypoints = reference_store.load_keypoints(db, ids[2])
    assert keypoints is not None
    with transaction(db):
        reference_store.save_keypoints(db, ids[2], dataclasses.replace(keypoints, position_xy=moved))
    second = store.positions(ids)
    assert np.array_equal(second[ids[2]], moved)
    assert np.array_equal(second[ids[0]], first[ids[0]])

    with transaction(db):
        sbow.save_vocabulary(db, map_id, {"centers": vocabulary.centroids})
    assert vocabulary_for(db, map_id) is vocabulary_for(db, map_id)  # decoded once
    replacement = vocabulary.centroids[::-1].copy()
    with transaction(db):
        sbow.save_vocabulary(db, map_id, {"centers": replacement})
    assert np.array_equal(vocabulary_for(db, map_id).centroids, replacement)
    db.close()


def test_the_stored_format_keeps_its_dtypes_and_reads_old_references() -> None:
    """Descriptors float16 and anchors float32/int32 on disk, float32 and float64/int64 read back; old defaults."""
    rng = np.random.default_rng(3)
    ref = _reference(rng, 1, n=12)
    alternative = MapAnchors(rng.random((12, 3)), rng.integers(-1, 9, 12), rng.integers(-1, 3, 12), rng.random(12))
    keypoints = dataclasses.replace(
        ref.keypoints(),
        alt_anchor_xyz=alternative.xyz,
        alt_anchor_facade_id=alternative.facade_id,
        alt_anchor_building_id=alternative.building_id,
        alt_anchor_distance_m=alternative.distance_m,
    )
    arrays = unpack_arrays(pack_arrays(keypoints.to_arrays()))
    assert list(arrays)[:3] == ["xy", "descriptors", "sizes"] and "alt_anchor_distance_m" in arrays
    assert arrays["descriptors"].dtype == np.float16 and arrays["anchor_xyz"].dtype == np.float32
    assert arrays["anchor_facade_id"].dtype == np.int32 and arrays["alt_anchor_building_id"].dtype == np.int32
    assert arrays["image_shape"].dtype == np.int64 and arrays["method"].item() == "rootsift"
    stored = StoredReference.from_keypoints(1, ReferenceKeypoints.from_arrays(arrays))
    assert stored.features.descriptors.dtype == np.float32
    assert np.array_equal(stored.features.descriptors, ref.features.descriptors.astype(np.float16).astype(np.float32))
    assert stored.anchors.xyz.dtype == np.float64 and stored.anchors.facade_id.dtype == np.int64
    assert np.array_equal(stored.anchors.xyz, ref.anchors.xyz.astype(np.float32).astype(np.float64))
    assert stored.alternative_anchors is not None
    assert np.array_equal(stored.alternative_anchors.facade_id, alternative.facade_id)
    assert stored.features.image_shape == (480, 640) and stored.features.scale == 1.0

    old = {name: arrays[name] for name in ("xy", "descriptors", "sizes", "angles", "responses", "image_shape")}
    old.update(scale=arrays["scale"], identity=arrays["identity"], building_ids=arrays["building_ids"])
    before = StoredReference.from_keypoints(2, ReferenceKeypoints.from_arrays(old))
    assert before.features.method == "rootsift" and before.alternative_anchors is None
    assert not before.anchors.valid.any() and np.isnan(before.anchors.xyz).all()
    assert before.anchors.facade_id.dtype == np.int64 and (before.anchors.building_id == -1).all()
    assert np.array_equal(before.position_covariance, np.eye(2) * UNKNOWN_POSITION_SIGMA_M**2)
    assert np.isnan(before.position_xy).all()
    assert np.isnan(ReferenceKeypoints.position_from_arrays(old)).all()
