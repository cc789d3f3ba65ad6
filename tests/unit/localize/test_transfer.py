"""Identity transfer: matching, RANSAC verification, votes spread over the query's building columns."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from contracts.settings import shared_dir
from geoloc.localize.identity import IdentityMap, identity_accuracy
from geoloc.localize.transfer import (
    ReferenceEvidence,
    match_features,
    rerank_by_inliers,
    transfer_identities,
    verify_matches,
)
from geoloc.vision.features import Features, extract_features
from tests.unit.localize.test_features_retrieval import load_rgb, rough_building_mask, textured_image

LUND = shared_dir() / "data" / "lund" / "images"


def halves_identity(mask: np.ndarray, left: int = 7, right: int = 9) -> IdentityMap:
    """Left half of the columns is building ``left``, right half ``right``."""
    w = mask.shape[1]
    prob = np.zeros((w, 2), np.float32)
    prob[: w // 2, 0] = 1.0
    prob[w // 2 :, 1] = 1.0
    return IdentityMap(np.array([left, right]), prob, mask)


# ----------------------------------------------------------------------------------------------
# Matching and verification


def test_match_features_recovers_a_permutation():
    f = extract_features(textured_image(), None, 400)
    perm = np.random.default_rng(0).permutation(len(f))
    g = f.subset(perm)
    pairs = match_features(g, f)
    assert len(pairs) > 0.8 * len(f)
    np.testing.assert_array_equal(perm[pairs[:, 0]], pairs[:, 1])
    assert len(np.unique(pairs[:, 1])) == len(pairs)  # one-to-one


def test_verify_matches_homography_with_outliers():
    rng = np.random.default_rng(1)
    q = rng.uniform(0, 1000, (150, 2))
    h = np.array([[1.1, 0.05, 30.0], [0.02, 0.95, -10.0], [1e-4, 0.0, 1.0]])
    ph = np.c_[q, np.ones(len(q))] @ h.T
    r = ph[:, :2] / ph[:, 2:] + rng.normal(0, 0.5, (len(q), 2))
    outlier = np.zeros(len(q), bool)
    outlier[:40] = True
    r[outlier] = rng.uniform(0, 1000, (40, 2))
    inl = verify_matches(q, r)
    assert inl[~outlier].mean() > 0.95
    assert inl[outlier].mean() < 0.1


def test_verify_matches_needs_enough_inliers():
    rng = np.random.default_rng(2)
    assert not verify_matches(rng.uniform(0, 500, (7, 2)), rng.uniform(0, 500, (7, 2))).any()
    assert not verify_matches(rng.uniform(0, 500, (60, 2)), rng.uniform(0, 500, (60, 2)), min_inliers=30).any()


# ----------------------------------------------------------------------------------------------
# Transfer


def test_transfer_on_a_known_warp_gives_the_building_of_every_column():
    """Query = reference zoomed 1.15x and shifted: query column x shows reference column (x + 60) / 1.15."""
    ref_rgb = textured_image(480, 640, seed=4)
    a = np.array([[1.15, 0.0, -60.0], [0.0, 1.15, -20.0]])
    q_rgb = cv2.warpAffine(ref_rgb, a, (640, 480), flags=cv2.INTER_LINEAR)
    ref_mask = np.ones((480, 640), bool)
    q_mask = np.ones((480, 640), bool)
    fr, fq = extract_features(ref_rgb, ref_mask), extract_features(q_rgb, q_mask)
    evidence = ReferenceEvidence.from_identity_map("ref", fr, halves_identity(ref_mask), score=1.0)
    result = transfer_identities(fq, q_mask, [evidence])
    assert result.references[0].n_inliers > 100
    ids, prob = result.identity.column_best()
    ref_col = (np.arange(640) + 0.5 + 60.0) / 1.15
    truth = np.where(ref_col < 320, 7, 9)
    seen = ref_col < 640
    assert np.mean(ids[seen] == truth[seen]) > 0.95
    assert prob[seen].mean() > 0.9
    boundary = [r for r in result.building_regions if r["building_id"] == 7][0]["x_end"]
    assert abs(boundary - (320 * 1.15 - 60)) < 15


def test_transfer_restricted_to_building_columns_and_connected_regions():
    ref_rgb = textured_image(480, 640, seed=5)
    mask = np.ones((480, 640), bool)
    fr = extract_features(ref_rgb, mask)
    evidence = ReferenceEvidence.from_identity_map("ref", fr, halves_identity(mask), score=1.0)
    q_mask = np.zeros((480, 640), bool)
    q_mask[:, :280] = True  # a region left of a gap
    q_mask[:, 300:] = True
    fq = extract_features(ref_rgb, q_mask)
    result = transfer_identities(fq, q_mask, [evidence])
    p = result.identity.column_prob
    assert np.all(p[280:300] == 0)  # no building pixels there
    assert np.all(p.sum(axis=1) <= 1 + 1e-5)
    ids, _ = result.identity.column_best()
    assert np.mean(ids[:280] == 7) > 0.95
    assert np.mean(ids[330:] == 9) > 0.95
    assert result.identity.pixel_ids().shape == q_mask.shape


def test_transfer_without_evidence_is_unknown():
    mask = np.ones((480, 640), bool)
    fq = extract_features(textured_image(seed=6), mask)
    fr = extract_features(textured_image(seed=7), mask)  # unrelated image
    evidence = ReferenceEvidence.from_identity_map("ref", fr, halves_identity(mask))
    result = transfer_identities(fq, mask, [evidence])
    assert result.references[0].n_inliers == 0
    assert np.all(result.identity.column_prob == 0)
    assert result.building_regions == []
    empty = transfer_identities(fq, mask, [])
    assert empty.identity.column_prob.shape == (640, 0)


@pytest.mark.skipif(not LUND.exists(), reason="shared Lund photos not available")
@pytest.mark.parametrize("pair", [(8, 9), (17, 18)])
def test_transfer_on_consecutive_lund_photos(pair: tuple[int, int]):
    """Reference: left half of its columns is building 7, right half 9.

    On the query, every inlier's column must carry the building of its reference keypoint's side, and
    both buildings appear left to right.
    """
    paths = sorted(LUND.glob("*.jpg"))
    feats, masks = [], []
    for i in pair:
        rgb = load_rgb(paths[i])
        masks.append(rough_building_mask(rgb))
        feats.append(extract_features(rgb, masks[-1]))
    fr, fq = feats
    evidence = ReferenceEvidence.from_identity_map(pair[0], fr, halves_identity(masks[0]), score=1.0)
    result = transfer_identities(fq, masks[1], [evidence])
    diag = result.references[0]
    assert diag.n_inliers >= 50
    truth = np.where(fr.xy[diag.pairs[:, 1], 0] < masks[0].shape[1] // 2, 7, 9)
    ids, _ = result.identity.column_best()
    got = ids[np.round(fq.xy[diag.pairs[:, 0], 0]).astype(int)]
    assert np.mean(got == truth) > 0.9
    # Most building columns get an identity; 7 lies left of 9.
    has_building = masks[1].any(axis=0)
    assert np.mean(result.identity.column_prob.sum(axis=1)[has_building] > 0.5) > 0.6
    regions = {r["building_id"]: r for r in result.building_regions}
    assert {7, 9} <= set(regions)
    assert regions[7]["x_start"] < regions[9]["x_start"]


# ----------------------------------------------------------------------------------------------
# A simulated pair (ground-truth building ids)


def column_identity(building_id: np.ndarray, mask: np.ndarray) -> IdentityMap:
    """Ground-truth identity map: each column gets its most frequent building id (one-hot)."""
    ids = np.unique(building_id[building_id >= 0])
    counts = (building_id[:, :, None] == ids[None, None, :]).sum(axis=0)  # (W, M)
    prob = ((counts == counts.max(axis=1, keepdims=True)) & (counts > 0)).astype(np.float32)
    prob /= np.maximum(prob.sum(axis=1, keepdims=True), 1.0)
    return IdentityMap(ids, prob, mask)


def test_transfer_on_a_simulated_pair():
    """Two views of a street canyon (two buildings, touching in the query).

    The right building on the columns both photos see, from the reference's ground-truth identities.
    """
    from geoloc.core.camera import Intrinsics
    from geoloc.sim import Pose, Scene, render
    from tests.scenes import street_canyon

    scene = Scene(street_canyon(), seed=3)
    intr = Intrinsics.from_hfov(640, 480, 70.0)
    ref = render(scene, Pose(-8.0, -21.0, 80.0), intr, seed=1)
    query = render(scene, Pose(-6.0, -15.0, 100.0), intr, seed=2)
    ref_mask, q_mask = ref.building_id >= 0, query.building_id >= 0
    fr, fq = extract_features(ref.rgb, ref_mask), extract_features(query.rgb, q_mask)
    evidence = ReferenceEvidence.from_identity_map("ref", fr, column_identity(ref.building_id, ref_mask), score=1.0)
    result = transfer_identities(fq, q_mask, [evidence])
    assert result.references[0].n_inliers >= 30
    # Columns both see: the query column's building is one the reference shows.
    seen = np.isin(query.building_id, np.unique(ref.building_id[ref_mask]))
    truth = np.where(seen, query.building_id, -1)
    assert identity_accuracy(result.identity.pixel_ids(), truth) > 0.85
    ids = {r["building_id"] for r in result.building_regions}
    assert ids == set(np.unique(truth[truth >= 0]).tolist())


def test_reference_evidence_scales_keypoints_to_its_identity_map():
    mask = np.ones((240, 320), bool)  # identity map at half the image resolution
    identity = halves_identity(mask)
    f = Features(
        np.array([[10.0, 10.0], [600.0, 400.0]]),
        np.full((2, 128), 128**-0.5),
        np.ones(2),
        np.zeros(2),
        np.ones(2),
        (480, 640),
    )
    ev = ReferenceEvidence.from_identity_map("r", f, identity)
    np.testing.assert_array_equal(ev.keypoint_prob, [[1, 0], [0, 1]])


def test_rerank_by_inliers_puts_the_overlapping_reference_first_and_its_match_is_reused():
    mask = np.ones((480, 640), bool)
    ref_rgb = textured_image(seed=8)
    q_rgb = cv2.warpAffine(ref_rgb, np.array([[1.1, 0.0, -30.0], [0.0, 1.1, -10.0]]), (640, 480))
    fq = extract_features(q_rgb, mask)
    fa, fb = extract_features(ref_rgb, mask), extract_features(textured_image(seed=9), mask)
    ranked = rerank_by_inliers(fq, [("b", 0.9, fb), ("a", 0.1, fa)], k=2)
    assert [m.reference_id for m in ranked] == ["a", "b"]
    assert ranked[0].n_inliers > 100 and ranked[1].n_inliers < 0.1 * ranked[0].n_inliers
    ev = ReferenceEvidence.from_identity_map("a", fa, halves_identity(mask), 0.1, match=ranked[0])
    reused = transfer_identities(fq, mask, [ev])
    fresh = transfer_identities(fq, mask, [ReferenceEvidence.from_identity_map("a", fa, halves_identity(mask), 0.1)])
    np.testing.assert_array_equal(reused.identity.column_prob, fresh.identity.column_prob)
