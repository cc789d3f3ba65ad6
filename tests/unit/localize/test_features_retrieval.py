"""Building-pixel RootSIFT features, the SBoW vocabulary and the TF-IDF inverted index."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from contracts.settings import models_dir, shared_dir
from geoloc.localize.retrieval import (
    Vocabulary,
    build_vocabulary,
    default_vocabulary,
    idf,
    tfidf_scores,
)
from geoloc.localize.sbow_index import SbowIndex
from geoloc.vision.features import Features, extract_features, root_sift
from geoloc.vision.model_files import vocabulary_path

LUND = shared_dir() / "data" / "lund" / "images"
CAMVID_TRAIN = shared_dir() / "data" / "camvid" / "train"


def textured_image(h: int = 480, w: int = 640, seed: int = 0) -> np.ndarray:
    """Random blocks (corners everywhere), blurred a little, RGB uint8."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (h // 16, w // 16, 3), dtype=np.uint8)
    img = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
    return cv2.GaussianBlur(img, (3, 3), 0)


def rough_building_mask(rgb: np.ndarray) -> np.ndarray:
    """A crude building mask for the Lund photos (no labels exist): not blue sky or white cloud, upper 72 % of rows."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    sky = (hsv[..., 0] > 90) & (hsv[..., 0] < 130) & (hsv[..., 1] > 40) & (hsv[..., 2] > 120)
    cloud = (hsv[..., 1] < 25) & (hsv[..., 2] > 225)
    mask = ~(sky | cloud)
    mask[int(0.72 * rgb.shape[0]) :] = False
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8)) > 0


def load_rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, path
    return img[..., ::-1].copy()


# ----------------------------------------------------------------------------------------------
# Features


def test_root_sift_rows_are_unit_and_square_roots_of_l1_normalised():
    rng = np.random.default_rng(1)
    sift = rng.uniform(0, 200, (50, 128)).astype(np.float32)
    rs = root_sift(sift)
    np.testing.assert_allclose(np.linalg.norm(rs, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(rs**2, sift / sift.sum(axis=1, keepdims=True), atol=1e-6)


def test_extract_features_shapes_normalisation_and_determinism():
    img = textured_image()
    f = extract_features(img, None, max_features=300)
    assert 100 < len(f) <= 300
    assert f.xy.shape == (len(f), 2) and f.xy.dtype == np.float32
    assert f.descriptors.shape == (len(f), 128) and f.descriptors.dtype == np.float32
    assert (f.descriptors >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(f.descriptors, axis=1), 1.0, atol=1e-4)
    assert np.all(np.diff(f.responses) <= 0)  # strongest first
    g = extract_features(img, None, max_features=300)
    np.testing.assert_array_equal(f.xy, g.xy)
    np.testing.assert_array_equal(f.descriptors, g.descriptors)


def test_features_only_on_the_dilated_building_mask():
    img = textured_image()
    mask = np.zeros(img.shape[:2], bool)
    mask[:, :200] = True
    f = extract_features(img, mask, dilate_px=4)
    assert len(f) > 50
    assert f.xy[:, 0].max() < 200 + 4 + 1
    assert len(extract_features(img, np.zeros_like(mask))) == 0


def test_large_images_are_downscaled_and_coordinates_returned_in_input_pixels(tmp_path: Path):
    img = textured_image(480, 640)
    big = cv2.resize(img, (1920, 1440), interpolation=cv2.INTER_CUBIC)  # 3x, downscaled back to 1024 wide
    f = extract_features(big, None, max_features=400)
    assert f.image_shape == (1440, 1920) and f.scale == pytest.approx(1024 / 1920)
    assert f.xy[:, 0].max() > 1024  # input pixels, not working pixels
    # The same content at the working size gives the same keypoints, scaled.
    work = cv2.resize(big, (1024, 768), interpolation=cv2.INTER_AREA)
    g = extract_features(work, None, max_features=400)
    d = np.linalg.norm(f.xy[:, None, :] * f.scale - g.xy[None, :, :], axis=2).min(axis=1)
    assert np.median(d) < 0.5
    f.save(tmp_path / "f.npz")
    h = Features.load(tmp_path / "f.npz")
    np.testing.assert_array_equal(h.xy, f.xy)
    np.testing.assert_allclose(h.descriptors, f.descriptors, atol=1e-3)
    assert h.scale == f.scale and h.image_shape == f.image_shape


# ----------------------------------------------------------------------------------------------
# Vocabulary


def test_vocabulary_words_are_nearest_centroids(tmp_path: Path):
    rng = np.random.default_rng(2)
    voc = Vocabulary(root_sift(rng.uniform(0, 1, (97, 128))))
    desc = root_sift(rng.uniform(0, 1, (1000, 128)))
    dist = ((desc[:, None, :].astype(np.float64) - voc.centroids[None]) ** 2).sum(axis=2)
    words = voc.words(desc, chunk=128)
    assert words.dtype == np.int32
    # The chosen word is a nearest centroid (random descriptors are nearly equidistant: compare distances).
    np.testing.assert_allclose(dist[np.arange(len(desc)), words], dist.min(axis=1), atol=1e-5)
    assert np.mean(words == dist.argmin(axis=1)) > 0.95
    voc.save(tmp_path / "v.npz")
    np.testing.assert_array_equal(Vocabulary.load(tmp_path / "v.npz").words(desc), words)


def test_build_vocabulary_is_deterministic_and_caps_words():
    rng = np.random.default_rng(3)
    desc = root_sift(rng.uniform(0, 1, (600, 128)))
    a = build_vocabulary(desc, 32, seed=5)
    b = build_vocabulary(desc, 32, seed=5)
    assert len(a) == 32
    np.testing.assert_array_equal(a.centroids, b.centroids)
    assert len(build_vocabulary(desc[:10], 32, seed=5)) == 10


# ----------------------------------------------------------------------------------------------
# Inverted index (the one SBoW index, SbowIndex, against the documented formula and tfidf_scores)

N_WORDS = 41  # words_st draws words 0..40


def dense_scores(docs: dict[int, np.ndarray], query: np.ndarray, n_words: int) -> dict[int, float]:
    """The documented formula, from scratch with dense histograms."""
    keys = list(docs)
    hist = np.stack([np.bincount(docs[k], minlength=n_words) for k in keys]).astype(float)
    df = (hist > 0).sum(axis=0)
    weights = np.where(df > 0, idf(np.maximum(df, 1), len(keys)), 0.0)
    q = np.bincount(query, minlength=n_words).astype(float)
    q /= max(q.sum(), 1)
    d = hist / np.maximum(hist.sum(axis=1, keepdims=True), 1)
    return dict(zip(keys, (np.minimum(d, q[None]) * weights).sum(axis=1).tolist(), strict=True))


words_st = st.lists(st.integers(0, 40), min_size=1, max_size=30).map(lambda v: np.array(v, np.int64))


@settings(max_examples=60, deadline=None)
@given(
    docs=st.dictionaries(st.integers(0, 30), words_st, min_size=1, max_size=12),
    extra=st.dictionaries(st.integers(100, 120), words_st, max_size=5),
    removed=st.sets(st.integers(0, 30), max_size=6),
    query=words_st,
)
def test_index_add_remove_matches_from_scratch(docs, extra, removed, query):
    index = SbowIndex(N_WORDS)
    for doc_id, words in {**docs, **extra}.items():
        index.add_words(doc_id, words)
    index.top(query, 3)  # score, then change
    for doc_id in extra:
        index.remove(doc_id)
    kept = {k: v for k, v in docs.items() if k not in removed}
    for doc_id in removed & set(docs):
        index.remove(doc_id)
    assert len(index) == len(kept)
    if not kept:
        assert index.top(query, 5) == []
        return
    scratch = SbowIndex.from_documents(N_WORDS, kept.items())
    keys_a, s_a = index.scores(query)
    keys_b, s_b = scratch.scores(query)
    a = dict(zip(keys_a, s_a.tolist(), strict=True))
    b = dict(zip(keys_b, s_b.tolist(), strict=True))
    expected = dense_scores(kept, query, 41)
    for k in kept:
        assert a[k] == pytest.approx(b[k], abs=1e-12)
        assert a[k] == pytest.approx(expected[k], abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(docs=st.lists(words_st, min_size=1, max_size=15), pick=st.integers(0, 100))
def test_identical_document_ranks_first(docs, pick):
    index = SbowIndex.from_documents(N_WORDS, enumerate(docs))
    target = pick % len(docs)
    ranked = index.top(docs[target], len(docs))
    top_score = ranked[0][1]
    assert dict(ranked)[target] == pytest.approx(top_score, rel=1e-12)


def test_tfidf_scores_from_postings_rows_like_a_database():
    """A database passes the rows of the query's words (and maybe others); doc indices are its candidates."""
    docs = {0: np.array([1, 1, 2, 3]), 1: np.array([2, 5, 5]), 2: np.array([7, 8])}
    index = SbowIndex.from_documents(100, docs.items())
    query = np.array([1, 2, 2, 5])
    rows = [
        (int(w), i, int(c))
        for i, k in enumerate(docs)
        for w, c in zip(*np.unique(docs[k], return_counts=True), strict=True)
    ]
    rows.append((99, 2, 4))  # a word the query lacks: ignored
    w, d, c = (np.array(v) for v in zip(*rows, strict=True))
    lengths = np.array([len(v) for v in docs.values()])
    got = tfidf_scores(query, w, d, c, lengths, n_docs=3)
    ids, expected = index.scores(query)
    assert ids.tolist() == [0, 1, 2]
    np.testing.assert_allclose(got, expected)
    assert got[2] == 0.0 and got[0] > 0 and got[1] > 0


# ----------------------------------------------------------------------------------------------
def plain_words(voc: Vocabulary, desc: np.ndarray) -> np.ndarray:
    """The nearest centroid as first written: argmin of ||c||^2 - 2 d.c in float32 (the ranking words() must keep)."""
    sq = np.einsum("ij,ij->i", voc.centroids, voc.centroids)
    return np.argmin(sq[None, :] - 2.0 * (desc @ voc.centroids.T), axis=1).astype(np.int32)


@pytest.mark.skipif(not LUND.exists(), reason="shared Lund data not available")
def test_vocabulary_words_equal_the_plain_formula_on_real_descriptors():
    """words() (half norms, subtraction in place) picks the plain formula's word exactly, repeated centroids too."""
    voc = default_vocabulary(models_dir()) if vocabulary_path(models_dir()).exists() else small_camvid_vocabulary()
    rgb = load_rgb(sorted(LUND.glob("*.jpg"))[0])
    desc = extract_features(rgb, rough_building_mask(rgb), 1500, max_side=768).descriptors
    np.testing.assert_array_equal(voc.words(desc, chunk=500), plain_words(voc, desc))
    doubled = Vocabulary(np.concatenate([voc.centroids[::-1], voc.centroids]))
    np.testing.assert_array_equal(doubled.words(desc), plain_words(doubled, desc))


# Retrieval on real photos


@lru_cache(maxsize=1)
def small_camvid_vocabulary() -> Vocabulary:
    """256 words from the building pixels of every 8th CamVid train image (a few seconds)."""
    from geoloc.core.labels import BUILDING

    descs = []
    for path in sorted((CAMVID_TRAIN / "images").glob("*.*"))[::8]:
        labels = cv2.imread(str(CAMVID_TRAIN / "labels" / f"{path.stem}.png"), cv2.IMREAD_UNCHANGED)
        descs.append(extract_features(load_rgb(path), labels == BUILDING, 600).descriptors)
    return build_vocabulary(np.concatenate(descs), 256, seed=0)


@pytest.mark.skipif(not (LUND.exists() and CAMVID_TRAIN.exists()), reason="shared Lund/CamVid data not available")
def test_lund_sequence_neighbours_rank_in_top4():
    """Consecutive Lund photos overlap: querying photo i (left out), photos i-1 and i+1 come in the top 4."""
    paths = sorted(LUND.glob("*.jpg"))[:14]
    voc = default_vocabulary(models_dir()) if vocabulary_path(models_dir()).exists() else small_camvid_vocabulary()
    words = []
    for p in paths:
        rgb = load_rgb(p)
        words.append(voc.words(extract_features(rgb, rough_building_mask(rgb), 800, max_side=768).descriptors))
    found, total = 0, 0
    for i in range(1, len(paths) - 1):
        index = SbowIndex.from_documents(voc.n_words, ((j, words[j]) for j in range(len(paths)) if j != i))
        top = [doc for doc, _ in index.top(words[i], 4)]
        found += (i - 1 in top) + (i + 1 in top)
        total += 2
    assert found / total >= 0.7, f"{found}/{total} neighbours in the top 4"
