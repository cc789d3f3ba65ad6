"""Matching and geometric verification of local features: a query against retrieved references.

1. :func:`match_features`: RootSIFT nearest neighbours by dot product (unit vectors: squared distance
   ``2 - 2 q.r``), Lowe's ratio test on distances, then one-to-one (each reference keypoint keeps only
   its best query keypoint).
2. :func:`verify_matches`: RANSAC (OpenCV USAC MAGSAC++) on a fundamental matrix and on a homography,
   in *working* pixels (``Features.scale``: longer side ~1024 px). A facade is a plane, where F is
   degenerate, so the homography's inliers are taken when they are nearly as many as F's
   (``planar_ratio``); otherwise F's. Fewer than ``min_inliers`` inliers: no inliers at all.

:func:`rerank_by_inliers` re-ranks an SBoW shortlist by verified inliers; its :class:`ReferenceMatch` carry
the inliers the identity transfer (:mod:`geoloc.localize.transfer`) votes with.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from geoloc.core.parallel import ONE_THREAD, JobThreads
from geoloc.vision.features import Features

DEFAULT_RATIO = 0.8
DEFAULT_MIN_INLIERS = 12
DEFAULT_THRESHOLD_PX = 3.0  # RANSAC threshold in working pixels (longer side ~1024)


@dataclass
class ReferenceMatch:
    """Diagnostics of one reference: matches after the ratio test, geometric inliers and the model used."""

    reference_id: Hashable
    score: float
    n_matches: int
    n_inliers: int
    model: str  # "F", "H" or "none"
    pairs: np.ndarray = field(repr=False)  # (n_inliers, 2) int (query index, reference index)
    putative: np.ndarray | None = field(default=None, repr=False)  # (n_matches, 2) all ratio-test pairs
    neighbours: Neighbours | None = field(default=None, repr=False)  # for matches at another ratio

    def as_dict(self) -> dict[str, Any]:
        """The match's figures as a JSON-ready dict (no arrays)."""
        return {
            "reference_id": self.reference_id,
            "score": self.score,
            "matches": self.n_matches,
            "inliers": self.n_inliers,
            "model": self.model,
        }


def match_features(query: Features, reference: Features, ratio: float = DEFAULT_RATIO, chunk: int = 2048) -> np.ndarray:
    """Putative matches: (K, 2) int64 (query index, reference index) pairs, sorted by query index.

    Nearest reference descriptor of each query descriptor (RootSIFT, Euclidean = Hellinger); kept when
    ``d1 < ratio * d2`` (Lowe) and when no other query keypoint matches the same reference keypoint closer.
    The same as ``ratio_matches(nearest_neighbours(query, reference, chunk), ratio)``.
    """
    return ratio_matches(nearest_neighbours(query, reference, chunk), ratio)


@dataclass(frozen=True)
class Neighbours:
    """Per query descriptor: index of the nearest reference descriptor and the distances to the two nearest.

    Independent of the ratio test's threshold, so matches at several ratios cost one search
    (:func:`ratio_matches`).
    """

    best: np.ndarray  # (Nq,) int64
    d1: np.ndarray  # (Nq,) float32
    d2: np.ndarray  # (Nq,) float32


def nearest_neighbours(query: Features, reference: Features, chunk: int = 2048) -> Neighbours | None:
    """The two nearest reference descriptors of each query descriptor (None when there are not two)."""
    nq, nr = len(query), len(reference)
    if nq == 0 or nr < 2:
        return None
    rt = reference.descriptors.T
    best = np.empty(nq, np.int64)
    d1 = np.empty(nq, np.float32)
    d2 = np.empty(nq, np.float32)
    for start in range(0, nq, chunk):
        sim = query.descriptors[start : start + chunk] @ rt
        rows = np.arange(len(sim))
        first = np.argmax(sim, axis=1)
        s1 = sim[rows, first]
        sim[rows, first] = -np.inf
        s2 = sim.max(axis=1)
        best[start : start + chunk] = first
        d1[start : start + chunk] = np.sqrt(np.maximum(2.0 - 2.0 * s1, 0.0))
        d2[start : start + chunk] = np.sqrt(np.maximum(2.0 - 2.0 * s2, 0.0))
    return Neighbours(best, d1, d2)


def ratio_matches(neighbours: Neighbours | None, ratio: float = DEFAULT_RATIO) -> np.ndarray:
    """:func:`match_features`'s pairs from the nearest neighbours: Lowe's ratio test, then one-to-one."""
    if neighbours is None:
        return np.zeros((0, 2), np.int64)
    best, d1, d2 = neighbours.best, neighbours.d1, neighbours.d2
    q = np.flatnonzero(d1 < ratio * d2)
    if len(q) == 0:
        return np.zeros((0, 2), np.int64)
    # One-to-one: per reference keypoint keep the closest query keypoint.
    order = np.lexsort((q, d1[q]))
    q = q[order]
    _, first_of = np.unique(best[q], return_index=True)
    q = np.sort(q[first_of])
    return np.stack([q, best[q]], axis=1).astype(np.int64)


def _inliers(mask: np.ndarray | None, n: int) -> np.ndarray:
    return np.zeros(n, bool) if mask is None else mask.reshape(-1).astype(bool)


def geometric_verification(
    q_xy: np.ndarray,
    r_xy: np.ndarray,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_inliers: int = DEFAULT_MIN_INLIERS,
    planar_ratio: float = 0.8,
    confidence: float = 0.999,
    max_iters: int = 2000,
) -> tuple[np.ndarray, str]:
    """RANSAC inliers of matched positions and the model kept ("F", "H" or "none"); see :func:`verify_matches`."""
    q = np.ascontiguousarray(q_xy, dtype=np.float64).reshape(-1, 2)
    r = np.ascontiguousarray(r_xy, dtype=np.float64).reshape(-1, 2)
    n = len(q)
    none = np.zeros(n, bool)
    if n < max(8, min_inliers):
        return none, "none"
    f_in = none
    try:
        f, f_mask = cv2.findFundamentalMat(q, r, cv2.USAC_MAGSAC, threshold_px, confidence, max_iters)
        if f is not None and f.shape == (3, 3):
            f_in = _inliers(f_mask, n)
    except cv2.error:
        pass
    h_in = none
    try:
        h, h_mask = cv2.findHomography(
            q, r, cv2.USAC_MAGSAC, 2.0 * threshold_px, maxIters=max_iters, confidence=confidence
        )
        if h is not None:
            h_in = _inliers(h_mask, n)
    except cv2.error:
        pass
    n_f, n_h = int(f_in.sum()), int(h_in.sum())
    if n_h >= min_inliers and n_h >= planar_ratio * n_f:
        return h_in, "H"
    if n_f >= min_inliers:
        return f_in, "F"
    return none, "none"


def verify_matches(
    q_xy: np.ndarray,
    r_xy: np.ndarray,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_inliers: int = DEFAULT_MIN_INLIERS,
    planar_ratio: float = 0.8,
) -> np.ndarray:
    """(K,) bool inlier mask of K matched positions ``q_xy``, ``r_xy`` (K, 2), by RANSAC.

    Fundamental matrix and homography (USAC MAGSAC++, homography threshold 2x, as its error is a transfer
    distance); the homography is kept when it has at least ``planar_ratio`` of F's inliers (a near-planar set,
    where F is ill-posed), else F. Fewer than ``min_inliers`` inliers (or fewer than 8 matches): all False.
    Positions and ``threshold_px`` in the same pixel units (working pixels, see :class:`Features`).
    """
    return geometric_verification(
        q_xy, r_xy, threshold_px=threshold_px, min_inliers=min_inliers, planar_ratio=planar_ratio
    )[0]


def match_and_verify(
    query: Features,
    reference: Features,
    *,
    ratio: float = DEFAULT_RATIO,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_inliers: int = DEFAULT_MIN_INLIERS,
) -> tuple[np.ndarray, np.ndarray, str]:
    """Putative matches (K, 2), their inlier mask (K,) and the model: match_features + verify_matches."""
    return _verify_pairs(query, reference, match_features(query, reference, ratio), threshold_px, min_inliers)


def _verify_pairs(
    query: Features, reference: Features, pairs: np.ndarray, threshold_px: float, min_inliers: int
) -> tuple[np.ndarray, np.ndarray, str]:
    if len(pairs) == 0:
        return pairs, np.zeros(0, bool), "none"
    q_xy = query.xy[pairs[:, 0]] * query.scale
    r_xy = reference.xy[pairs[:, 1]] * reference.scale
    inliers, model = geometric_verification(q_xy, r_xy, threshold_px=threshold_px, min_inliers=min_inliers)
    return pairs, inliers, model


def rerank_by_inliers(
    query: Features,
    candidates: Sequence[tuple[Hashable, float, Features]],
    k: int = 8,
    *,
    ratio: float = DEFAULT_RATIO,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_inliers: int = DEFAULT_MIN_INLIERS,
    threads: JobThreads = ONE_THREAD,
) -> list[ReferenceMatch]:
    """Spatial re-ranking: the ``k`` candidates with the most RANSAC inliers (ties: higher retrieval score).

    candidates: (reference id, retrieval score, features) of a longer SBoW shortlist (e.g. 20).
    threads: the candidates are matched on these (the result does not depend on their number).
    Returns their :class:`ReferenceMatch` (pass each as ``ReferenceEvidence.match`` to skip re-matching; its
    ``neighbours`` give matches at another ratio without a second search).
    Measured on a simulated Helsinki world (60 references, 30 queries): shortlist 20 -> top 8 by inliers
    puts the reference sharing most building area in the top 4 for 54 % of queries instead of 25 %.
    """

    def match(candidate: tuple[Hashable, float, Features]) -> ReferenceMatch:
        ref_id, score, feats = candidate
        neighbours = nearest_neighbours(query, feats)
        pairs, inliers, model = _verify_pairs(query, feats, ratio_matches(neighbours, ratio), threshold_px, min_inliers)
        return ReferenceMatch(
            ref_id, float(score), len(pairs), int(inliers.sum()), model, pairs[inliers], pairs, neighbours
        )

    out = threads.map(match, candidates)
    order = sorted(range(len(out)), key=lambda i: (-out[i].n_inliers, -out[i].score, i))
    return [out[i] for i in order[:k]]
