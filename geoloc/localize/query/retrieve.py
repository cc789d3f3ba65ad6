"""Retrieval and identity transfer: the SBoW shortlist re-ranked by verified inliers, the top k's identities."""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

from geoloc.core.parallel import ONE_THREAD, JobThreads
from geoloc.localize.grid import PositionPrior
from geoloc.localize.identity import IdentityMap
from geoloc.localize.matching import ReferenceMatch, rerank_by_inliers
from geoloc.localize.query.config import PRIOR_SHORTLIST_FACTOR, QueryConfig
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.store import ReferenceStore, StoredReference
from geoloc.localize.transfer import ReferenceEvidence, transfer_identities
from geoloc.vision.evidence import PhotoEvidence
from geoloc.vision.features import Features


def retrieve(
    features: Features,
    store: ReferenceStore,
    vocabulary: Vocabulary,
    config: QueryConfig,
    position_prior: PositionPrior | None = None,
    *,
    threads: JobThreads = ONE_THREAD,
) -> tuple[dict[Hashable, StoredReference], list[ReferenceMatch]]:
    """SBoW shortlist of ``config.shortlist`` references re-ranked by verified inliers (best first).

    threads: the re-ranking matches the references on these (the result does not depend on their number).

    With a position prior, references that stand too far from it to see what the query sees (beyond
    ``prior_sigmas`` prior sigmas plus ``view_range_m``) are left out before the shortlist is cut: repeated
    facade elements elsewhere in the city otherwise pass as matches.
    """
    words = vocabulary.words(features.descriptors)
    wanted = config.shortlist * (PRIOR_SHORTLIST_FACTOR if position_prior is not None else 1)
    ranked = store.shortlist(words, wanted)
    if position_prior is not None:
        # Positions first: only the references kept are loaded (features are the costly part to read).
        reach = config.prior_sigmas * position_prior.sigma_m + config.view_range_m
        positions = store.positions([ref_id for ref_id, _ in ranked])
        ranked = [(ref_id, score) for ref_id, score in ranked if ref_id in positions]
        xy = np.array([positions[ref_id] for ref_id, _ in ranked], dtype=float).reshape(-1, 2)
        known = np.all(np.isfinite(xy), axis=1)
        near = np.ones(len(xy), dtype=bool)  # a reference with no position is kept
        near[known] = position_prior.distances_m(xy[known]) <= reach  # one call: a shape's distance is costly
        ranked = [pair for pair, keep in zip(ranked, near.tolist(), strict=True) if keep]
    stored = store.load([ref_id for ref_id, _ in ranked[: config.shortlist]])
    shortlist = [(ref_id, score) for ref_id, score in ranked if ref_id in stored][: config.shortlist]
    stored = {ref_id: stored[ref_id] for ref_id, _ in shortlist}
    candidates = [(ref_id, score, stored[ref_id].features) for ref_id, score in shortlist]
    return stored, rerank_by_inliers(features, candidates, len(candidates), threads=threads)


def transfer(
    evidence: PhotoEvidence, stored: dict[Hashable, StoredReference], matches: Sequence[ReferenceMatch], k: int
) -> IdentityMap:
    """The paper's identity transfer from the top ``k`` re-ranked references."""
    evidences = [_reference_evidence(stored[m.reference_id], m) for m in matches[:k]]
    return transfer_identities(evidence.features, evidence.building_mask, evidences).identity


def _reference_evidence(ref: StoredReference, match: ReferenceMatch) -> ReferenceEvidence:
    return ReferenceEvidence(ref.reference_id, ref.features, ref.keypoint_prob, ref.building_ids, match.score, match)


def identity_trust(
    stored: dict[Hashable, StoredReference],
    matches: Sequence[ReferenceMatch],
    k: int,
    position_prior: PositionPrior | None,
    view_m: float,
) -> float:
    """How far to trust the identities the top ``k`` references transfer, by how near the nearest one stands.

    ``exp(-d^2 / (2 (sigma^2 + view_m^2)))`` of the nearest one's distance d (m) to the position prior, sigma the
    prior's (m): two cameras that see one facade stand within a few view distances of each other, and a reference
    150 m from the query that shares repeated shop fronts with it transfers the buildings it sees, which the query
    does not. 1 without a prior, with ``view_m`` 0, or when a reference's position is unknown.
    """
    if position_prior is None or view_m <= 0:
        return 1.0
    xy = np.array([stored[m.reference_id].position_xy for m in matches[:k]], dtype=float).reshape(-1, 2)
    if len(xy) == 0 or not np.all(np.isfinite(xy)):
        return 1.0
    nearest_m = float(position_prior.distances_m(xy).min())
    return float(np.exp(-0.5 * nearest_m**2 / (position_prior.sigma_m**2 + view_m**2)))
