"""The map-anchored pose: PnP proposals on the query's matches to the references' anchored keypoints."""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

from geoloc.core.parallel import ONE_THREAD, JobThreads
from geoloc.localize.absolute_pose import PoseEstimate, estimate_pose_from_groups, group_proposal
from geoloc.localize.matching import ReferenceMatch, match_features, ratio_matches
from geoloc.localize.query.config import QueryConfig
from geoloc.localize.store import StoredReference
from geoloc.photos.photo import Photo
from geoloc.vision.features import Features


def anchored_pose(
    query_features: Features,
    matches: Sequence[ReferenceMatch],
    stored: dict[Hashable, StoredReference],
    photo: Photo,
    config: QueryConfig,
    *,
    threads: JobThreads = ONE_THREAD,
) -> list[tuple[PoseEstimate, list[Hashable]]]:
    """PnP on the query's matches to the anchored keypoints of the given references.

    threads: each reference group's PnP proposal runs on these (the result does not depend on their number).

    Returns the estimate with the references that contributed inliers, and a second one where the
    ambiguous references (:attr:`StoredReference.alternative_anchors`) use their runner-up pose's anchors;
    estimates with fewer than ``config.pnp_min_inliers`` inliers are left out (so the list may be empty).
    """
    pairs_of: list[tuple[StoredReference, np.ndarray]] = []
    for match in matches:
        ref = stored.get(match.reference_id)
        if ref is not None:
            # The re-ranking's nearest neighbours give the looser ratio's matches without a second search.
            pairs = (
                ratio_matches(match.neighbours, config.anchor_ratio)
                if match.neighbours is not None
                else match_features(query_features, ref.features, config.anchor_ratio)
            )
            pairs_of.append((ref, pairs))
    variants = [False]
    if any(ref.alternative_anchors is not None for ref, _ in pairs_of):
        variants.append(True)
    # Each variant's groups, keyed (reference index, alternative anchors used): a reference without
    # alternative anchors brings the same group to both variants, so its RANSAC runs once.
    group_of: dict[tuple[int, bool], tuple[np.ndarray, np.ndarray]] = {}
    variant_keys: list[list[tuple[int, bool]]] = []
    for use_alternative in variants:
        keys = []
        for index, (ref, pairs) in enumerate(pairs_of):
            alternative_anchors = ref.alternative_anchors if use_alternative else None
            anchors = alternative_anchors if alternative_anchors is not None else ref.anchors
            valid = anchors.valid[pairs[:, 1]] if len(pairs) else np.zeros(0, bool)
            if valid.sum() < 4:
                continue
            key = (index, alternative_anchors is not None)
            group_of[key] = (anchors.xyz[pairs[valid, 1]], query_features.xy[pairs[valid, 0]])
            keys.append(key)
        variant_keys.append(keys)
    proposals = threads.map(
        lambda group: group_proposal(
            *group, photo.intrinsics, threshold_px=config.pnp_threshold_px, max_iters=config.pnp_max_iters
        ),
        group_of.values(),
    )
    proposal_of = dict(zip(group_of, proposals, strict=True))
    out = []
    for keys in variant_keys:
        estimate, owner = estimate_pose_from_groups(
            [group_of[key] for key in keys],
            photo.intrinsics,
            threshold_px=config.pnp_threshold_px,
            min_inliers=config.pnp_min_inliers,
            proposals=[proposal_of[key] for key in keys],
        )
        if estimate is not None:
            refs = [pairs_of[keys[i][0]][0].reference_id for i in np.unique(owner[estimate.inliers])]
            out.append((estimate, refs))
    return out
