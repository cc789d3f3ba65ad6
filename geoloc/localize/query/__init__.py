"""The query stage: one photo -> ranked continuous poses with uncertainty, a heatmap and its buildings.

This is the one retrieval / re-rank / transfer / localise stage; the workers' query job and
``geoloc eval world`` both call :func:`geolocate` (its one entry, :mod:`.stage`) with a :class:`QueryConfig`
(:mod:`.config`; the evaluation's ground-truth identity ablation calls its two steps, ``retrieve_and_transfer``
and ``locate``, with its own identities), and only the source of the stored references differs
(:class:`geoloc.localize.store.ReferenceStore`: the database for the service, memory for the evaluation,
:class:`geoloc.evaluation.store.InMemoryReferenceStore`; both rank with
:class:`geoloc.localize.sbow_index.SbowIndex`'s scores, :func:`geoloc.localize.retrieval.tfidf_scores`).

Steps, one module each:

1. Retrieval (:mod:`.retrieve`): SBoW top ``shortlist`` references, re-ranked by RANSAC-verified inliers
   (:func:`geoloc.localize.matching.rerank_by_inliers`).
2. Identity transfer from the top ``k`` (the paper's step; :mod:`.retrieve`,
   :func:`geoloc.localize.transfer.transfer_identities`).
3. Map-anchored pose (beyond the paper, :mod:`.anchored`): the query's matches to the top ``anchor_references``
   references meet those references' keypoints back-projected onto the map's facades (:mod:`geoloc.localize.anchors`);
   the 2D-3D correspondences give a pose by PnP + RANSAC (:mod:`geoloc.localize.absolute_pose`).
4. The paper's likelihood on a grid (identity-aware or geometry-only, :mod:`geoloc.localize.grid`) with the
   position and heading priors; its best poses are refined continuously (:mod:`geoloc.localize.refinement`).
5. Trust (:mod:`.trust`): the anchored pose is trusted when it has enough inliers, is physically plausible
   (outside buildings, at a hand-held height, nearly level), agrees with the position prior, and the map's
   likelihood at it is not far below the likelihood's own best (the likelihood checks, it does not compete).
6. Fusion (:mod:`.fusion`): a trusted anchored pose is refined against the map with the anchored pose as a
   prior and becomes rank 1; otherwise the likelihood's poses stand. Uncertainty: each pose carries the
   radius of its 90 % region: from the PnP covariance plus the anchoring references' own pose uncertainty for
   an anchored pose, from the posterior's mass around the pose for a likelihood pose.
7. The answer (:mod:`.answer`): poses, identities (read from the map at a trusted anchored pose), buildings.
"""

from geoloc.localize.query.anchored import anchored_pose
from geoloc.localize.query.answer import AnswerPose, QueryAnswer
from geoloc.localize.query.config import PRESETS, QueryConfig, preset_config
from geoloc.localize.query.retrieve import retrieve, transfer
from geoloc.localize.query.stage import geolocate

__all__ = [
    "PRESETS",
    "AnswerPose",
    "QueryAnswer",
    "QueryConfig",
    "anchored_pose",
    "geolocate",
    "preset_config",
    "retrieve",
    "transfer",
]
