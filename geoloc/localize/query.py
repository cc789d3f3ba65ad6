"""The query stage: one photo -> ranked continuous poses with uncertainty, a heatmap and its buildings.

This is the one retrieval / re-rank / transfer / localise stage; the workers' query job and
``geoloc eval world`` both call :func:`geolocate` with a :class:`QueryConfig`, and only the source of the
stored references differs (:class:`ReferenceStore`: the database for the service, memory for the
evaluation; both rank with :func:`geoloc.localize.retrieval.tfidf_scores`).

Steps:

1. Retrieval: SBoW top ``shortlist`` references, re-ranked by RANSAC-verified inliers
   (:func:`geoloc.localize.transfer.rerank_by_inliers`).
2. Identity transfer from the top ``k`` (the paper's step; :func:`geoloc.localize.transfer.transfer_identities`).
3. Map-anchored pose (beyond the paper): the query's matches to the top ``anchor_references`` references
   meet those references' keypoints back-projected onto the map's facades (:mod:`geoloc.localize.anchors`); the
   2D-3D correspondences give a pose by PnP + RANSAC (:mod:`geoloc.localize.absolute_pose`).
4. The paper's likelihood on a grid (identity-aware or geometry-only, :mod:`geoloc.localize.grid`) with the
   position and heading priors; its best poses are refined continuously (:mod:`geoloc.localize.refinement`).
5. Fusion: the anchored pose is trusted when it has enough inliers, is physically plausible (outside
   buildings, at a hand-held height, nearly level), agrees with the position prior, and the map's
   likelihood at it is not far below the likelihood's own best (the likelihood checks, it does not
   compete). A trusted anchored pose is then refined against the map with the anchored pose as a prior,
   becomes rank 1, and its buildings are read from the map; otherwise the likelihood's poses stand.
6. Uncertainty: each pose carries the radius of its 90 % region: from the PnP covariance plus the
   anchoring references' own pose uncertainty for an anchored pose, from the posterior's mass around the
   pose for a likelihood pose.
"""

from __future__ import annotations

import math
import time
from collections.abc import Hashable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from geoloc.core.context import MethodContext
from geoloc.core.parallel import ONE_THREAD, JobThreads
from geoloc.localize.absolute_pose import PoseEstimate, estimate_pose_from_groups, group_proposal
from geoloc.localize.grid import Localization, PositionPrior, localize
from geoloc.localize.identity import IdentityMap
from geoloc.localize.labeling import column_building_ids, identity_from_poses
from geoloc.localize.likelihood import known_building_heights, pose_likelihood
from geoloc.localize.posterior import DEFAULT_SHARPNESS
from geoloc.localize.refinement import refine_pose
from geoloc.localize.retrieval import InvertedIndex, Vocabulary
from geoloc.localize.store import ReferenceStore, StoredReference
from geoloc.localize.transfer import (
    ReferenceEvidence,
    ReferenceMatch,
    match_features,
    ratio_matches,
    rerank_by_inliers,
    transfer_identities,
)
from geoloc.maps import CityMap
from geoloc.maps.raycast import cast_panoramas
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import PhotoEvidence, image_model_with_identity
from geoloc.vision.features import Features
from geoloc.vision.image_model import ImageModel

SPARE_POSES = 3
"""Likelihood poses asked beyond ``top_n``: ones that coincide after refinement (or with the anchored pose)
are dropped, and the spares keep the answer at ``top_n`` locations."""
PRIOR_SHORTLIST_FACTOR = 3
"""With a position prior, this many times the shortlist is ranked before far references are left out."""
CHI2_2D_90 = 4.605
"""90 % quantile of the chi-square distribution with 2 degrees of freedom (2D position regions)."""


@dataclass(frozen=True)
class QueryConfig:
    """Every knob of the query stage, recorded with each answer (``search.config``) and evaluation.

    Retrieval and transfer: ``shortlist`` SBoW candidates are re-ranked by verified inliers; the top ``k``
    transfer their identities (the paper's k).
    Likelihood: ``use_identity`` (False: the paper's geometry-only baseline), the grid ``cell_m`` x
    ``n_yaws`` (over the prior's region, else within ``search_radius_m`` of the identified buildings), the
    posterior ``likelihood ** sharpness x priors``, and ``refine_poses`` best poses refined continuously.
    Anchors: ``use_anchors`` (False: the paper's likelihood alone); the query is matched (Lowe ratio
    ``anchor_ratio``, looser than retrieval's: the PnP's RANSAC rejects outliers) to the
    ``anchor_references`` best references; PnP inlier threshold ``pnp_threshold_px``.
    With a position prior, references farther than ``prior_sigmas`` prior sigmas plus ``view_range_m``
    from it are not retrieved.
    Trust: at least ``pnp_min_inliers`` inliers; a camera ``max_height_error_m`` from hand height and
    within ``max_pitch_deg`` of level; within ``prior_sigmas`` of the position prior; below
    ``strong_inliers``, the likelihood at the pose must reach ``min_likelihood_ratio`` of the grid's best
    (repeated facade elements let wrong references pass RANSAC with a few inliers).
    Uncertainty: a likelihood pose's radius holds 90 % of the posterior tempered to
    ``likelihood ** uncertainty_sharpness``; each anchoring reference is credited at least
    ``anchor_sigma_floor_m``; a trusted pose is refined on the map when ``refine_anchored``.
    """

    shortlist: int = 20
    k: int = 4
    anchor_references: int = 6
    use_identity: bool = True
    use_anchors: bool = True
    cell_m: float = 10.0
    search_radius_m: float = 80.0
    n_yaws: int = 120
    refine_poses: int = 3
    sharpness: float = DEFAULT_SHARPNESS
    uncertainty_sharpness: float = 0.1
    pnp_threshold_px: float = 4.0
    pnp_min_inliers: int = 20
    anchor_ratio: float = 0.9
    strong_inliers: int = 30
    min_likelihood_ratio: float = 0.8
    max_height_error_m: float = 2.0
    max_pitch_deg: float = 20.0
    prior_sigmas: float = 3.0
    view_range_m: float = 100.0
    anchor_sigma_floor_m: float = 5.0
    refine_anchored: bool = True

    def as_dict(self) -> dict[str, float | int | bool]:
        """The configuration as a JSON-ready dict."""
        return asdict(self)


@dataclass
class AnswerPose:
    """One ranked answer (local frame): position, yaw, probability and the radius of its 90 % region.

    source: "anchors" (PnP on map-anchored reference points, refined on the map) or "likelihood".
    """

    rank: int
    x_m: float
    y_m: float
    yaw_deg: float
    probability: float
    uncertainty_radius_m: float
    source: str
    likelihood: float = float("nan")
    inliers: int = 0


@dataclass
class QueryAnswer:
    """A geolocated query: ranked poses, the likelihood's probability map, identities and evidence used.

    localization: the likelihood's grid search (its heatmap is the answer's probability map). identity:
    the query's per-column identities (read from the map at the anchored pose when one is trusted, else
    transferred). transferred: the paper's transferred identities. anchored: the PnP estimate (trusted or
    not) and ``search`` says which.
    """

    poses: list[AnswerPose]
    localization: Localization
    identity: IdentityMap
    transferred: IdentityMap
    buildings: list[dict[str, Any]]
    references: list[dict[str, Any]]
    anchored: PoseEstimate | None
    search: dict[str, Any]
    timings_ms: dict[str, float] = field(default_factory=dict)


def geolocate(
    city_map: CityMap,
    photo: Photo,
    evidence: PhotoEvidence,
    store: ReferenceStore,
    vocabulary: Vocabulary,
    config: QueryConfig = QueryConfig(),
    *,
    position_prior: PositionPrior | None = None,
    prior_yaw_deg: float | None = None,
    top_n: int = 10,
    identity_override: IdentityMap | None = None,
    context: MethodContext,
) -> QueryAnswer:
    """Geolocate a photo (its evidence already analysed) against the references of ``store``.

    position_prior: optional Gaussian prior (e.g. the photo's GPS). prior_yaw_deg: optional heading prior
    (local bearing). identity_override: use these identities instead of the transferred ones (evaluation
    ablation: ground-truth identities). context: the job threads (the matching and the PnP proposals run on
    them; the answer does not depend on their number). Positions are local metres of ``city_map.frame``.
    """
    timings: dict[str, float] = dict(evidence.timings_ms)
    t0 = time.perf_counter()
    stored, matches = retrieve(evidence.features, store, vocabulary, config, position_prior, threads=context.threads)
    timings["retrieval"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    transferred = transfer(evidence, stored, matches, config.k)
    identity = identity_override if identity_override is not None else transferred
    model = image_model_with_identity(evidence, identity, photo.intrinsics)
    timings["transfer"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    candidates = []
    if config.use_anchors:
        references = matches[: config.anchor_references]
        candidates = anchored_pose(evidence.features, references, stored, photo, config, threads=context.threads)
    timings["anchors"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    localization = localize(
        city_map,
        model,
        use_identity=config.use_identity,
        position_prior=position_prior,
        prior_yaw_deg=prior_yaw_deg,
        cell_m=config.cell_m,
        search_radius_m=config.search_radius_m,
        n_yaws=config.n_yaws,
        sharpness=config.sharpness,
        top_n=top_n + SPARE_POSES,
    )
    timings["localize"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    use_identity = bool(localization.search["identity"])
    # Each candidate is checked; of the trusted ones (a reference's two readings, at most) the map and the
    # prior pick the one that explains the query best.
    anchored: PoseEstimate | None = None
    anchor_refs: list[Hashable] = []
    trust, checks, best_key = False, {}, (False, -1.0)
    for estimate, refs in candidates:
        ok, candidate_checks, lik = _trust_anchored(
            city_map, model, estimate, localization, position_prior, use_identity, config
        )
        key = (ok, lik * _prior_weight(position_prior, estimate))
        if anchored is None or key > best_key:
            anchored, anchor_refs, checks, trust, best_key = estimate, refs, candidate_checks, ok, key
    poses: list[AnswerPose] = []
    if trust and anchored is not None:
        poses.append(_anchored_answer(city_map, model, anchored, anchor_refs, stored, use_identity, config))
    poses += _likelihood_answers(city_map, model, localization, use_identity, position_prior, config, poses)
    poses = _rank(poses, top_n)
    timings["fuse"] = 1e3 * (time.perf_counter() - t0)

    final_identity = identity
    if trust and identity_override is None:
        final_identity = _identity_at(city_map, poses[0], evidence, photo)
    buildings: list[dict[str, Any]] = []
    for entry in final_identity.building_extents():
        building = city_map.buildings[entry["building_id"]]
        buildings.append({**entry, "osm_id": building.osm_id, "name": building.name})
    search = dict(localization.search)
    search.update(
        anchors={
            "trusted": bool(trust),
            "inliers": 0 if anchored is None else anchored.n_inliers,
            "references": [str(r) for r in anchor_refs],
            "checks": checks,
        },
        config=config.as_dict(),
    )
    return QueryAnswer(
        poses,
        localization,
        final_identity,
        transferred,
        buildings,
        [m.as_dict() for m in matches[: max(config.k, config.anchor_references)]],
        anchored,
        search,
        timings,
    )


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
        centre = np.array([position_prior.x_m, position_prior.y_m])
        positions = store.positions([ref_id for ref_id, _ in ranked])
        ranked = [
            (ref_id, score)
            for ref_id, score in ranked
            if ref_id in positions
            and (not np.all(np.isfinite(positions[ref_id])) or np.hypot(*(positions[ref_id] - centre)) <= reach)
        ]
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
        lambda group: group_proposal(*group, photo.intrinsics, threshold_px=config.pnp_threshold_px),
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


def _prior_weight(position_prior: PositionPrior | None, estimate: PoseEstimate) -> float:
    if position_prior is None:
        return 1.0
    return float(position_prior.weights(np.array([[estimate.pose.x_m, estimate.pose.y_m]]))[0])


def _reference_evidence(ref: StoredReference, match: ReferenceMatch) -> ReferenceEvidence:
    return ReferenceEvidence(ref.reference_id, ref.features, ref.keypoint_prob, ref.building_ids, match.score, match)


def _likelihood_at(
    city_map: CityMap, model: ImageModel, x_m: float, y_m: float, yaw_deg: float, use_identity: bool
) -> float:
    panorama = cast_panoramas(city_map, np.array([[x_m, y_m]]), bearing_step_deg=model.bin_deg)
    lik = pose_likelihood(
        panorama,
        model,
        np.array([yaw_deg]),
        use_identity=use_identity,
        building_height_m=known_building_heights(city_map),
    )
    return float(lik[0, 0])


def _trust_anchored(
    city_map: CityMap,
    model: ImageModel,
    anchored: PoseEstimate,
    localization: Localization,
    position_prior: PositionPrior | None,
    use_identity: bool,
    config: QueryConfig,
) -> tuple[bool, dict[str, object], float]:
    """Whether the anchored pose is trusted, the value of each check, and the likelihood at the pose."""
    pose = anchored.pose
    checks: dict[str, object] = {
        "inliers": anchored.n_inliers,
        "height_m": round(pose.height_m, 2),
        "pitch_deg": round(anchored.pitch_deg, 2),
    }
    ok = anchored.n_inliers >= config.pnp_min_inliers
    ok &= abs(pose.height_m - 1.6) <= config.max_height_error_m
    ok &= abs(anchored.pitch_deg) <= config.max_pitch_deg
    if position_prior is not None:
        distance = math.hypot(pose.x_m - position_prior.x_m, pose.y_m - position_prior.y_m)
        checks["prior_distance_m"] = round(distance, 1)
        ok &= distance <= config.prior_sigmas * position_prior.sigma_m
    lik = _likelihood_at(city_map, model, pose.x_m, pose.y_m, pose.yaw_deg, use_identity)
    best = float(localization.likelihood.max(initial=0.0))
    checks["likelihood"] = round(lik, 4)
    checks["likelihood_best"] = round(best, 4)
    if anchored.n_inliers < config.strong_inliers:
        # Repeated facade elements let a wrong reference pass RANSAC with a few inliers: the map must agree.
        ok &= lik >= config.min_likelihood_ratio * best
    return bool(ok), checks, lik


def _anchored_answer(
    city_map: CityMap,
    model: ImageModel,
    anchored: PoseEstimate,
    anchor_refs: list[Hashable],
    stored: dict[Hashable, StoredReference],
    use_identity: bool,
    config: QueryConfig,
) -> AnswerPose:
    """The anchored pose refined on the map (prior: the PnP position and the references' uncertainty)."""
    anchor_cov = np.mean([stored[r].position_covariance for r in anchor_refs], axis=0) if anchor_refs else np.eye(2)
    anchor_cov = anchor_cov + np.eye(2) * config.anchor_sigma_floor_m**2
    pnp_cov = anchored.covariance[:2, :2]
    total = anchor_cov + (pnp_cov if np.all(np.isfinite(pnp_cov)) else 0.0)
    sigma = math.sqrt(float(np.linalg.eigvalsh(total).max()))
    pose = anchored.pose
    if not config.refine_anchored:
        radius = math.sqrt(CHI2_2D_90) * sigma
        lik = _likelihood_at(city_map, model, pose.x_m, pose.y_m, pose.yaw_deg, use_identity)
        return AnswerPose(1, pose.x_m, pose.y_m, pose.yaw_deg % 360.0, 1.0, radius, "anchors", lik, anchored.n_inliers)
    refined = refine_pose(
        city_map,
        model,
        pose.x_m,
        pose.y_m,
        pose.yaw_deg,
        prior_xy=(pose.x_m, pose.y_m),
        prior_sigma_m=sigma,
        half_size_m=min(6.0, 2.0 * sigma),
        use_identity=use_identity,
        sharpness=config.sharpness,
    )
    radius = math.sqrt(CHI2_2D_90 * float(np.linalg.eigvalsh(refined.position_covariance).max()))
    return AnswerPose(
        1,
        refined.x_m,
        refined.y_m,
        refined.yaw_deg,
        1.0,
        radius,
        "anchors",
        refined.likelihood,
        anchored.n_inliers,
    )


def _likelihood_answers(
    city_map: CityMap,
    model: ImageModel,
    localization: Localization,
    use_identity: bool,
    position_prior: PositionPrior | None,
    config: QueryConfig,
    already: list[AnswerPose],
) -> list[AnswerPose]:
    """The likelihood's poses, the best ``refine_poses`` refined continuously, with 90 % radii.

    The radius holds 90 % of a tempered posterior (likelihood ** ``uncertainty_sharpness`` x prior): the
    sharpened posterior that ranks the poses is too sure of itself to say how far the truth may be.
    """
    positions = localization.positions
    tempered = np.power(np.clip(localization.likelihood.astype(float), 0.0, None), config.uncertainty_sharpness)
    heat = tempered.sum(axis=1)
    if position_prior is not None:
        heat = heat * position_prior.weights(positions)
    answers: list[AnswerPose] = []
    for i, pose in enumerate(localization.poses):
        x, y, yaw, lik = pose.x_m, pose.y_m, pose.yaw_deg, float(pose.likelihood)
        if i < config.refine_poses:
            refined = refine_pose(
                city_map,
                model,
                x,
                y,
                yaw,
                prior_xy=None if position_prior is None else (position_prior.x_m, position_prior.y_m),
                prior_sigma_m=None if position_prior is None else position_prior.sigma_m,
                half_size_m=config.cell_m / 2.0 + 1.0,
                use_identity=use_identity,
                sharpness=config.sharpness,
            )
            x, y, yaw, lik = refined.x_m, refined.y_m, refined.yaw_deg, refined.likelihood
        radius = _mass_radius(positions, heat, np.array([x, y]), 0.9, config.cell_m)
        if any(math.hypot(x - a.x_m, y - a.y_m) < config.cell_m / 2.0 for a in already + answers):
            continue
        answers.append(AnswerPose(0, x, y, yaw, float(pose.probability), radius, "likelihood", lik))
    return answers


def _mass_radius(positions: np.ndarray, mass: np.ndarray, centre: np.ndarray, share: float, cell_m: float) -> float:
    """Smallest radius around ``centre`` holding ``share`` of the (P,) mass at ``positions`` (plus half a cell)."""
    total = float(mass.sum())
    if total <= 0 or len(positions) == 0:
        return float("inf")
    distance = np.hypot(*(positions - centre).T)
    order = np.argsort(distance)
    cumulative = np.cumsum(mass[order]) / total
    index = int(np.searchsorted(cumulative, share))
    return float(distance[order][min(index, len(order) - 1)] + cell_m / 2.0)


def _rank(poses: list[AnswerPose], top_n: int) -> list[AnswerPose]:
    """Probabilities: a trusted anchored pose keeps most of the mass; ranks follow the list order."""
    if poses and poses[0].source == "anchors":
        rest = sum(p.probability for p in poses[1:])
        anchored_share = 0.8
        poses[0].probability = anchored_share if len(poses) > 1 else 1.0
        for p in poses[1:]:
            p.probability = (1.0 - anchored_share) * p.probability / rest if rest > 0 else 0.0
    poses = poses[:top_n]
    for rank, pose in enumerate(poses, start=1):
        pose.rank = rank
    return poses


def _identity_at(city_map: CityMap, pose: AnswerPose, evidence: PhotoEvidence, photo: Photo) -> IdentityMap:
    """The query's per-column building identities read from the map at a trusted pose (greedy labelling)."""
    model = evidence.image_model
    panorama = cast_panoramas(city_map, np.array([[pose.x_m, pose.y_m]]), bearing_step_deg=model.bin_deg)
    ids = column_building_ids(panorama, np.array([pose.yaw_deg]), photo.intrinsics, model.offsets_deg, model.bin_deg)
    return identity_from_poses(ids[0, 0][None, :], np.ones(1), evidence.building_mask)


class InMemoryReferenceStore:
    """Labelled references and their SBoW index held in memory (the evaluation's :class:`ReferenceStore`)."""

    def __init__(self, vocabulary: Vocabulary) -> None:
        self.vocabulary = vocabulary
        self.index = InvertedIndex()
        self.references: dict[Hashable, StoredReference] = {}

    def add(self, reference: StoredReference) -> None:
        """Index a labelled reference (replacing one with the same id)."""
        self.index.add(reference.reference_id, self.vocabulary.words(reference.features.descriptors))
        self.references[reference.reference_id] = reference

    def shortlist(self, words: np.ndarray, n: int) -> list[tuple[Hashable, float]]:
        """The ``n`` best references by SBoW score."""
        return self.index.query(words, n)

    def load(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, StoredReference]:
        """The references of these ids."""
        return {ref_id: self.references[ref_id] for ref_id in reference_ids if ref_id in self.references}

    def positions(self, reference_ids: Sequence[Hashable]) -> dict[Hashable, np.ndarray]:
        """The estimated positions of these references."""
        return {ref_id: self.references[ref_id].position_xy for ref_id in reference_ids if ref_id in self.references}
