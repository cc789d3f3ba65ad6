"""The query stage's entry, :func:`geolocate`: retrieval, transfer, anchors, the grid, fusion, the answer."""

from __future__ import annotations

import time
from typing import Any

from geoloc.core.context import MethodContext
from geoloc.localize.grid import PositionPrior, localize
from geoloc.localize.identity import IdentityMap
from geoloc.localize.likelihood import LikelihoodOptions
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.query.anchored import anchored_pose
from geoloc.localize.query.answer import AnswerPose, QueryAnswer, building_entries, identity_at
from geoloc.localize.query.config import SPARE_POSES, QueryConfig
from geoloc.localize.query.fusion import anchored_answer, likelihood_answers, rank_poses
from geoloc.localize.query.retrieve import identity_trust, retrieve, transfer
from geoloc.localize.query.trust import choose_anchored
from geoloc.localize.retrieval import Vocabulary
from geoloc.localize.store import ReferenceStore
from geoloc.maps import CityMap
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.photos.photo import Photo
from geoloc.vision.evidence import PhotoEvidence, image_model_with_identity


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
    identity_override: IdentityMap | None = None,
    context: MethodContext,
) -> QueryAnswer:
    """Geolocate a photo (its evidence already analysed) against the references of ``store``.

    position_prior: optional Gaussian prior (e.g. the photo's GPS). heading_prior: a :class:`HeadingPrior` (the
    compass's robust one, or a stated heading's Gaussian: :func:`geoloc.localize.reference.heading_prior_at`).
    identity_override: use these identities instead of the transferred ones (evaluation
    ablation: ground-truth identities). context: the job threads (the matching and the PnP proposals run on
    them; the answer does not depend on their number). Positions are local metres of ``city_map.frame``.

    The photo's image model with its identities is built once, and one :class:`MapLikelihood` of it
    serves the grid, the trust checks, the refinements and the identities read at a trusted pose.
    """
    timings: dict[str, float] = dict(evidence.timings_ms)
    t0 = time.perf_counter()
    stored, matches = retrieve(evidence.features, store, vocabulary, config, position_prior, threads=context.threads)
    timings["retrieval"] = 1e3 * (time.perf_counter() - t0)

    t0 = time.perf_counter()
    transferred = transfer(evidence, stored, matches, config.k)
    identity = identity_override if identity_override is not None else transferred
    model = image_model_with_identity(evidence, identity, photo.intrinsics)
    trust = 1.0  # ground-truth identities (the evaluation's ceiling) are trusted
    if identity_override is None:
        trust = identity_trust(stored, matches, config.k, position_prior, config.identity_view_m)
    options = LikelihoodOptions(use_identity=config.use_identity, identity_trust=trust)
    likelihood = MapLikelihood(city_map, model, options)
    timings["transfer"] = 1e3 * (time.perf_counter() - t0)

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
    likelihood = likelihood.with_options(use_identity=bool(localization.search["identity"]))
    choice = choose_anchored(likelihood, candidates, localization, position_prior, config)
    poses: list[AnswerPose] = []
    if choice.trusted and choice.estimate is not None:
        poses.append(anchored_answer(likelihood, choice.estimate, choice.references, stored, config))
    poses += likelihood_answers(likelihood, localization, position_prior, config, poses)
    poses = rank_poses(poses, top_n)
    timings["fuse"] = 1e3 * (time.perf_counter() - t0)

    final_identity = identity
    if choice.trusted and identity_override is None:
        final_identity = identity_at(likelihood, poses[0], evidence.building_mask, photo.intrinsics)
    search: dict[str, Any] = dict(localization.search)
    search.update(
        identity_trust=round(trust, 4),
        anchors={
            "trusted": bool(choice.trusted),
            "inliers": 0 if choice.estimate is None else choice.estimate.n_inliers,
            "references": [str(r) for r in choice.references],
            "checks": choice.checks,
        },
        config=config.as_dict(),
    )
    return QueryAnswer(
        poses,
        localization,
        final_identity,
        transferred,
        building_entries(city_map, final_identity),
        [m.as_dict() for m in matches[: max(config.k, config.anchor_references)]],
        choice.estimate,
        search,
        timings,
    )
