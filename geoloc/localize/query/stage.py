"""The query stage's entry, :func:`geolocate`: retrieval, transfer, anchors, the grid, fusion, the answer.

Two steps: :func:`retrieve_and_transfer` and :func:`locate` (with the identities an :class:`IdentityUse`
names); the evaluation's ablation with ground-truth identities calls them with its own
(:func:`geoloc.evaluation.queries.geolocate_with_identities`).
"""

from __future__ import annotations

import time
from collections.abc import Hashable
from dataclasses import dataclass

from contracts.answers import AnchorsUsed, QuerySearch
from geoloc.core.context import MethodContext
from geoloc.localize.grid import PositionPrior, localize
from geoloc.localize.identity import IdentityMap
from geoloc.localize.likelihood import LikelihoodOptions
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.matching import ReferenceMatch
from geoloc.localize.query.anchored import anchored_pose
from geoloc.localize.query.answer import AnswerPose, QueryAnswer, identity_at
from geoloc.localize.query.config import SPARE_POSES, QueryConfig
from geoloc.localize.query.fusion import anchored_answer, likelihood_answers, rank_poses
from geoloc.localize.query.retrieve import identity_trust, retrieve, transfer
from geoloc.localize.query.trust import choose_anchored
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.store import ReferenceStore, StoredReference
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import PhotoEvidence, image_model_with_identity


@dataclass(frozen=True)
class Retrieved:
    """What retrieval and identity transfer found for a query (:func:`retrieve_and_transfer`).

    stored: the shortlisted references; matches: their verified matches, best first; transferred: the
    identities transferred from the top ``k``; timings_ms: the evidence's timings with ``retrieval`` and
    ``transfer`` added.
    """

    stored: dict[Hashable, StoredReference]
    matches: list[ReferenceMatch]
    transferred: IdentityMap
    timings_ms: dict[str, float]


@dataclass(frozen=True)
class IdentityUse:
    """The identities the grid and the checks use (:func:`locate`).

    identity: the identities (:func:`geolocate`: the transferred ones); trust: how far the likelihood trusts
    them; read_at_trusted_pose: whether a trusted anchored pose reads them again from the map.
    """

    identity: IdentityMap
    trust: float
    read_at_trusted_pose: bool = True


def geolocate(
    city_map: CityMap,
    photo: Photo,
    evidence: PhotoEvidence,
    store: ReferenceStore,
    vocabulary: Vocabulary,
    config: QueryConfig = QueryConfig(),
    *,
    position_prior: PositionPrior | None = None,
    heading_prior: HeadingPrior | None = None,
    top_n: int = 10,
    context: MethodContext,
) -> QueryAnswer:
    """Geolocate a photo (its evidence already analysed) against the references of ``store``.

    position_prior: optional Gaussian prior (e.g. the photo's GPS). heading_prior: a :class:`HeadingPrior` (the
    compass's robust one, or a stated heading's Gaussian: :func:`geoloc.localize.reference.heading_prior_at`).
    context: the job threads (the matching and the PnP proposals run on them; the answer does not depend on
    their number). Positions are local metres of ``city_map.frame``. :func:`retrieve_and_transfer`, then
    :func:`locate` with the transferred identities, trusted as far as the retrieval supports them.
    """
    retrieved = retrieve_and_transfer(evidence, store, vocabulary, config, position_prior, context)
    t0 = time.perf_counter()
    trust = identity_trust(retrieved.stored, retrieved.matches, config.k, position_prior, config.identity_view_m)
    retrieved.timings_ms["transfer"] += 1e3 * (time.perf_counter() - t0)  # the trust is the transfer's
    use = IdentityUse(retrieved.transferred, trust)
    return locate(city_map, photo, evidence, retrieved, use, config, position_prior, heading_prior, top_n, context)


def retrieve_and_transfer(
    evidence: PhotoEvidence,
    store: ReferenceStore,
    vocabulary: Vocabulary,
    config: QueryConfig,
    position_prior: PositionPrior | None,
    context: MethodContext,
) -> Retrieved:
    """The query's shortlist re-ranked by verified inliers, and the identities transferred from its top ``k``."""
    timings: dict[str, float] = dict(evidence.timings_ms)
    t0 = time.perf_counter()
    stored, matches = retrieve(evidence.features, store, vocabulary, config, position_prior, threads=context.threads)
    timings["retrieval"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    transferred = transfer(evidence, stored, matches, config.k)
    timings["transfer"] = 1e3 * (time.perf_counter() - t0)
    return Retrieved(stored, matches, transferred, timings)


def locate(
    city_map: CityMap,
    photo: Photo,
    evidence: PhotoEvidence,
    retrieved: Retrieved,
    use: IdentityUse,
    config: QueryConfig,
    position_prior: PositionPrior | None,
    heading_prior: HeadingPrior | None,
    top_n: int,
    context: MethodContext,
) -> QueryAnswer:
    """Anchors, the grid, fusion and the answer of a retrieved query, with the identities of ``use``.

    The photo's image model with those identities is built once, and one :class:`MapLikelihood` of it serves
    the grid, the trust checks, the refinements and the identities read at a trusted pose.
    """
    stored, matches, transferred = retrieved.stored, retrieved.matches, retrieved.transferred
    timings = dict(retrieved.timings_ms)
    identity, trust = use.identity, use.trust
    t0 = time.perf_counter()
    model = image_model_with_identity(evidence, identity, photo.intrinsics)
    options = LikelihoodOptions(use_identity=config.use_identity, identity_trust=trust)
    likelihood = MapLikelihood(city_map, model, options)
    timings["transfer"] += 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    candidates = []
    if config.use_anchors:
        references = matches[: config.anchor_references]
        candidates = anchored_pose(evidence.features, references, stored, photo, config, threads=context.threads)
    timings["anchors"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    localization = localize(
        likelihood,
        config.grid,
        position_prior=position_prior,
        heading_prior=heading_prior,
        top_n=top_n + SPARE_POSES,
    )
    timings["localize"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    # The checks and refinements use the likelihood the grid used (geometry only without identity evidence).
    likelihood = likelihood.with_options(use_identity=localization.search.identity)
    choice = choose_anchored(likelihood, candidates, localization, position_prior, config)
    poses: list[AnswerPose] = []
    if choice.trusted and choice.estimate is not None:
        poses.append(anchored_answer(likelihood, choice.estimate, choice.references, stored, config))
    poses += likelihood_answers(likelihood, localization, position_prior, config, poses)
    poses = rank_poses(poses, top_n)
    timings["fuse"] = 1e3 * (time.perf_counter() - t0)

    final_identity = identity
    if choice.trusted and use.read_at_trusted_pose:
        final_identity = identity_at(likelihood, poses[0], evidence.building_mask, photo.intrinsics)
    search = QuerySearch(
        **localization.search.model_dump(),
        identity_trust=round(trust, 4),
        anchors=AnchorsUsed(
            trusted=bool(choice.trusted),
            inliers=0 if choice.estimate is None else choice.estimate.n_inliers,
            references=[str(r) for r in choice.references],
            checks=choice.checks,
        ),
        config=config.as_dict(),
    )
    return QueryAnswer(
        poses,
        localization,
        final_identity,
        transferred,
        final_identity.building_extents(),
        matches[: max(config.k, config.anchor_references)],
        choice.estimate,
        search,
        timings,
    )
