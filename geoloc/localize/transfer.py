"""Identity transfer: building identities of retrieved references carried onto a query through matched features.

Paper, "Geolocation of the query view": SIFT features of a reference carry the building-identity
probabilities of their pixels; when matched as geometric inliers, those probabilities are transferred to
the query, giving each building region of the query an identity and a horizontal extent.

Steps (:func:`transfer_identities`):

1., 2. Matching and verification (:mod:`geoloc.localize.matching`, whose names this module re-exports:
   :func:`match_features`, :func:`verify_matches`, :func:`rerank_by_inliers`, ...).
3. Votes: every inlier votes its reference keypoint's identity distribution (rows may sum to < 1) at
   its query column, inside the *connected building region* (8-connected component of the query's
   building mask) that holds the keypoint. Votes from the k references add up (each inlier counts
   once, so a reference weighs by its number of inliers; the retrieval score is only reported).
   A reference with fewer than ``min_relative_inliers`` (0.5) of the best reference's inliers does not
   vote: on a simulated world, weakly verified pairs are mostly matches to another building with
   similar elements (only ~8 % of pairs with 12-20 inliers matched the right building).
4. Spreading (:func:`_spread_votes`), per region and only over the columns where that region has
   pixels, so each building's horizontal extent follows the mask: a column's distribution is that of
   the nearby votes (Gaussian, ``sigma_frac`` of the width), or, away from votes, that of the nearest
   column with votes, so a boundary between two buildings of one region falls midway between their
   nearest inliers. Its confidence (the row sum) is ``min(1, votes within ~fill_frac of the width /
   min_evidence)``: 1 near enough inliers, fading to 0 (unknown) away from them. Columns without
   building pixels, or in regions without any inlier, are 0.

All of it is vectorised over keypoints, columns and buildings; Python loops run only over references.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import TypedDict

import cv2
import numpy as np
from scipy import ndimage

from geoloc.localize.identity import IdentityMap
from geoloc.localize.matching import (
    DEFAULT_MIN_INLIERS,
    DEFAULT_RATIO,
    DEFAULT_THRESHOLD_PX,
    Neighbours,
    ReferenceMatch,
    geometric_verification,
    match_and_verify,
    match_features,
    nearest_neighbours,
    ratio_matches,
    rerank_by_inliers,
    verify_matches,
)
from geoloc.vision.features import Features

__all__ = [
    "DEFAULT_MIN_INLIERS",
    "DEFAULT_RATIO",
    "DEFAULT_THRESHOLD_PX",
    "BuildingRegion",
    "Neighbours",
    "QueryIdentity",
    "ReferenceEvidence",
    "ReferenceMatch",
    "geometric_verification",
    "match_and_verify",
    "match_features",
    "nearest_neighbours",
    "ratio_matches",
    "rerank_by_inliers",
    "transfer_identities",
    "verify_matches",
]


@dataclass
class ReferenceEvidence:
    """What a retrieved reference brings to the transfer.

    reference_id: its id. features: its :class:`Features`. keypoint_prob: (N, M_r) identity probabilities
    of its keypoints over ``building_ids`` (M_r,). score: its retrieval score (reported, not used as a weight).
    match: its verified match with the query when already computed (:func:`rerank_by_inliers`), else None.
    """

    reference_id: Hashable
    features: Features
    keypoint_prob: np.ndarray
    building_ids: np.ndarray
    score: float = 0.0
    match: ReferenceMatch | None = None

    def __post_init__(self) -> None:
        """Coerce ``building_ids`` to (M,) int64 and ``keypoint_prob`` to (N, M) float32."""
        self.building_ids = np.asarray(self.building_ids, dtype=np.int64).reshape(-1)
        self.keypoint_prob = np.asarray(self.keypoint_prob, dtype=np.float32).reshape(
            len(self.features), len(self.building_ids)
        )

    @classmethod
    def from_identity_map(
        cls,
        reference_id: Hashable,
        features: Features,
        identity: IdentityMap,
        score: float = 0.0,
        match: ReferenceMatch | None = None,
    ) -> ReferenceEvidence:
        """Probabilities of the keypoints read from the reference's :class:`IdentityMap`.

        The identity map may be at another resolution than the image the features come from; keypoint
        positions are scaled to it.
        """
        h, w = features.image_shape
        ih, iw = identity.building_mask.shape
        xy = features.xy * np.array([iw / w, ih / h], np.float32)
        return cls(reference_id, features, identity.probabilities_at(xy), identity.building_ids, score, match)


@dataclass
class QueryIdentity:
    """Result of :func:`transfer_identities`.

    identity: the query's :class:`IdentityMap` (union of the references' building ids; rows sum to <= 1).
    evidence: (W,) float32 total vote mass per column (in inlier votes). references: per-reference diagnostics.
    building_regions: runs of columns with the same most probable building (:class:`BuildingRegion`),
    widest first.
    """

    identity: IdentityMap
    evidence: np.ndarray
    references: list[ReferenceMatch]
    building_regions: list[BuildingRegion]


class BuildingRegion(TypedDict):
    """A run of columns of the query whose most probable building is the same.

    x_start, x_end: first and last column (inclusive, pixels of the mask). probability: the building's mean
    identity probability over the run; evidence: the mean vote mass per column (inlier votes).
    """

    building_id: int
    x_start: int
    x_end: int
    probability: float
    evidence: float


def _working_mask(mask: np.ndarray, max_width: int) -> tuple[np.ndarray, float]:
    """The building mask at a width of at most ``max_width`` (nearest) and the factor working / mask columns."""
    h, w = mask.shape
    if w <= max_width:
        return mask, 1.0
    f = max_width / w
    small = cv2.resize(mask.astype(np.uint8), (max_width, max(1, round(h * f))), interpolation=cv2.INTER_NEAREST)
    return small > 0, f


def _keypoint_components(labels: np.ndarray, xy: np.ndarray, reach_px: int = 8) -> np.ndarray:
    """Component label at each (x, y) working-pixel position, 0 for none.

    Keypoints just off the mask (features are detected on a dilated mask) take a component within
    ``reach_px`` pixels (the largest label there).
    """
    h, w = labels.shape
    x = np.clip(np.round(xy[:, 0]).astype(np.int64), 0, w - 1)
    y = np.clip(np.round(xy[:, 1]).astype(np.int64), 0, h - 1)
    comp = labels[y, x].astype(np.int64)
    off = comp == 0
    if off.any():
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach_px + 1, 2 * reach_px + 1))
        near = cv2.dilate(labels.astype(np.float32), kernel)  # labels are exact in float32 (< 2**24)
        comp[off] = near[y[off], x[off]].astype(np.int64)
    return comp


def _peak_gaussian(x: np.ndarray, sigma: float, axis: int) -> np.ndarray:
    """Gaussian filter along ``axis`` with a kernel of peak 1 (a unit vote reads 1 at its own column)."""
    return ndimage.gaussian_filter1d(x, sigma, axis=axis, mode="constant", truncate=4.0) * np.float32(
        np.sqrt(2.0 * np.pi) * sigma
    )


def _spread_votes(
    raw: np.ndarray,
    presence: np.ndarray,
    *,
    sigma: float,
    fill_length: float,
    min_evidence: float,
    min_support: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-column identity probabilities from column votes, region by region.

    raw: (C, W, M) vote mass of each region's inliers at their columns. presence: (C, W) bool, the columns
    each region covers. Returns column probabilities (W, M) (rows sum to <= 1) and evidence (W,).

    Per region, the *distribution* of a column is that of the local evidence ``E = G_sigma * raw``
    (Gaussian along the columns, peak 1) normalised, ``E / sum_m E``, where ``sum_m E >= min_support``;
    the region's other columns copy the distribution of the nearest such column, so the boundary between
    two buildings of one region falls midway between their nearest votes (not where one has more votes).
    The *confidence* (row sum) is ``min(1, (G_fill * sum_m raw) / min_evidence)``: the number of votes
    within about ``fill_length`` columns, so it fades away from the matched parts.
    """
    n_comp, w, m = raw.shape
    local = _peak_gaussian(raw, sigma, axis=1) * presence[:, :, None]
    support = local.sum(axis=2)  # (C, W)
    wide = _peak_gaussian(raw.sum(axis=2), max(fill_length, 0.5), axis=1) * presence  # (C, W)
    confidence = np.minimum(1.0, wide / min_evidence)
    prob = np.zeros((w, m), np.float32)
    for c in range(n_comp):  # regions that hold votes (few)
        valid = np.flatnonzero(presence[c] & (support[c] >= min_support))
        if len(valid) == 0:
            continue
        target = np.flatnonzero(presence[c])
        pos = np.searchsorted(valid, target)
        left = np.maximum(pos - 1, 0)
        right = np.minimum(pos, len(valid) - 1)
        nearest = valid[np.where(target - valid[left] <= valid[right] - target, left, right)]
        dist_c = local[c, nearest] / support[c, nearest, None]
        prob[target] += dist_c * confidence[c, target, None]
    # Two regions stacked in one column: keep the sum at most 1.
    prob /= np.maximum(prob.sum(axis=1, keepdims=True), 1.0)
    return prob, wide.sum(axis=0)


def _regions(ids: np.ndarray, prob: np.ndarray, evidence: np.ndarray, min_width: int) -> list[BuildingRegion]:
    """Runs of equal building id (>= 0) along the columns, at least ``min_width`` columns wide, widest first."""
    if len(ids) == 0:
        return []
    change = np.flatnonzero(np.diff(ids) != 0) + 1
    starts = np.r_[0, change]
    ends = np.r_[change, len(ids)]  # exclusive
    cum_p = np.r_[0.0, np.cumsum(prob, dtype=np.float64)]
    cum_e = np.r_[0.0, np.cumsum(evidence, dtype=np.float64)]
    keep = (ids[starts] >= 0) & (ends - starts >= min_width)
    out = [
        BuildingRegion(
            building_id=int(ids[s]),
            x_start=int(s),
            x_end=int(e - 1),
            probability=float((cum_p[e] - cum_p[s]) / (e - s)),
            evidence=float((cum_e[e] - cum_e[s]) / (e - s)),
        )
        for s, e in zip(starts[keep], ends[keep], strict=True)
    ]
    return sorted(out, key=lambda r: (-(r["x_end"] - r["x_start"]), r["x_start"]))


@dataclass(frozen=True)
class TransferOptions:
    """The knobs of :func:`transfer_identities`.

    ratio, threshold_px, min_inliers: matching and RANSAC (see :func:`match_and_verify`).
    min_relative_inliers: a reference votes only with at least this share of the best reference's inliers.
    sigma_frac: Gaussian width of the local vote evidence along the columns, as a share of the image width.
    fill_frac, min_evidence: a column's confidence is min(1, votes within ~fill_frac of the width (Gaussian
    weights) / min_evidence).
    region_min_probability, region_min_width_frac: a building region needs this column probability and width.
    work_width: the spreading runs at most at this many columns (then is resampled to the mask's width).
    """

    ratio: float = DEFAULT_RATIO
    threshold_px: float = DEFAULT_THRESHOLD_PX
    min_inliers: int = DEFAULT_MIN_INLIERS
    min_relative_inliers: float = 0.5
    sigma_frac: float = 0.02
    min_evidence: float = 2.0
    fill_frac: float = 0.15
    region_min_probability: float = 0.3
    region_min_width_frac: float = 0.01
    work_width: int = 1024


def transfer_identities(
    query_features: Features,
    query_building_mask: np.ndarray,
    references: Sequence[ReferenceEvidence],
    options: TransferOptions = TransferOptions(),
) -> QueryIdentity:
    """Building identities of the query's columns from its matches with retrieved references (module docstring).

    query_features: the query's :class:`Features`. query_building_mask: (H, W) bool building pixels of the
    query (any resolution; the result's columns are its columns). references: the k retrieved references.
    options: :class:`TransferOptions`.
    Returns a :class:`QueryIdentity`.
    """
    ratio, threshold_px, min_inliers = options.ratio, options.threshold_px, options.min_inliers
    sigma_frac, min_evidence, fill_frac = options.sigma_frac, options.min_evidence, options.fill_frac
    min_relative_inliers, work_width = options.min_relative_inliers, options.work_width
    region_min_probability, region_min_width_frac = options.region_min_probability, options.region_min_width_frac
    mask = np.asarray(query_building_mask).astype(bool)
    full_h, full_w = mask.shape
    ids_union = np.unique(np.concatenate([r.building_ids for r in references])) if references else np.zeros(0, np.int64)
    m = len(ids_union)

    # Match every reference; collect inlier votes (query keypoint index, distribution over the union ids).
    diagnostics: list[ReferenceMatch] = []
    for ref in references:
        if ref.match is not None:
            diagnostics.append(ref.match)
            continue
        pairs, inliers, model = match_and_verify(
            query_features, ref.features, ratio=ratio, threshold_px=threshold_px, min_inliers=min_inliers
        )
        good = pairs[inliers]
        diagnostics.append(
            ReferenceMatch(ref.reference_id, float(ref.score), len(pairs), len(good), model, good, pairs)
        )
    most = max((d.n_inliers for d in diagnostics), default=0)
    vote_kp: list[np.ndarray] = []
    vote_dist: list[np.ndarray] = []
    for ref, diag in zip(references, diagnostics, strict=True):
        if diag.n_inliers == 0 or diag.n_inliers < min_relative_inliers * most or len(ref.building_ids) == 0:
            continue
        dist = np.zeros((diag.n_inliers, m), np.float32)
        dist[:, np.searchsorted(ids_union, ref.building_ids)] = ref.keypoint_prob[diag.pairs[:, 1]]
        vote_kp.append(diag.pairs[:, 0])
        vote_dist.append(dist)

    # Connected building regions at working width, and the columns each covers.
    work_mask, f = _working_mask(mask, work_width)
    wh, ww = work_mask.shape
    _, labels = cv2.connectedComponents(work_mask.astype(np.uint8), connectivity=8)
    prob_work = np.zeros((ww, m), np.float32)
    total = np.zeros(ww, np.float32)
    if vote_kp and m:
        kp = np.concatenate(vote_kp)
        dist = np.concatenate(vote_dist)
        img_h, img_w = query_features.image_shape
        xy = query_features.xy[kp] * np.array([ww / img_w, wh / img_h], np.float32)
        comp = _keypoint_components(labels, xy)
        on = comp > 0
        used, slot = np.unique(comp[on], return_inverse=True)
        cols = np.clip(np.round(xy[on, 0]).astype(np.int64), 0, ww - 1)
        raw = np.zeros((len(used), ww, m), np.float32)
        np.add.at(raw, (slot, cols), dist[on])
        # presence[c, x]: component used[c] has a pixel in column x.
        sel = np.isin(labels, used)
        presence = np.zeros((len(used), ww), bool)
        presence[np.searchsorted(used, labels[sel]), np.nonzero(sel)[1]] = True
        prob_work, total = _spread_votes(
            raw, presence, sigma=max(sigma_frac * ww, 0.5), fill_length=fill_frac * ww, min_evidence=min_evidence
        )

    # Back to the mask's columns (nearest working column); zero where the column has no building pixel.
    src = np.minimum(((np.arange(full_w) + 0.5) * f).astype(np.int64), ww - 1)
    has_building = np.asarray(mask.any(axis=0))  # (W,): the mask is 2-D
    column_prob = prob_work[src] * has_building[:, None]
    evidence = (total[src] * has_building).astype(np.float32)
    identity = IdentityMap(ids_union, column_prob, mask)

    best_ids, best_prob = identity.column_best(region_min_probability)
    regions = _regions(best_ids, best_prob, evidence, max(1, round(region_min_width_frac * full_w)))
    return QueryIdentity(identity, evidence, diagnostics, regions)
