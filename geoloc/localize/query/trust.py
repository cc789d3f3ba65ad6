"""Trust checks of the anchored pose: enough inliers, physically plausible, near the prior, the map agrees.

The likelihood checks, it does not compete: below ``strong_inliers`` inliers the map's likelihood at the
anchored pose must reach ``min_likelihood_ratio`` of the grid's best. Of the trusted candidates (a
reference's two readings, at most) the map and the prior pick the one that explains the query best.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field

import numpy as np

from geoloc.localize.absolute_pose import PoseEstimate
from geoloc.localize.grid import Localization, PositionPrior
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.query.config import QueryConfig


@dataclass
class AnchorChoice:
    """The anchored pose kept (trusted or not; None without any), the references it rests on and its checks."""

    estimate: PoseEstimate | None = None
    references: list[Hashable] = field(default_factory=list)
    trusted: bool = False
    checks: dict[str, int | float] = field(default_factory=dict)


def choose_anchored(
    likelihood: MapLikelihood,
    candidates: Sequence[tuple[PoseEstimate, list[Hashable]]],
    localization: Localization,
    position_prior: PositionPrior | None,
    config: QueryConfig,
) -> AnchorChoice:
    """Check each candidate (:func:`trust_anchored`); keep the trusted one the map and the prior like best."""
    choice = AnchorChoice()
    best_key = (False, -1.0)
    for estimate, refs in candidates:
        ok, checks, lik = trust_anchored(likelihood, estimate, localization, position_prior, config)
        key = (ok, lik * _prior_weight(position_prior, estimate))
        if choice.estimate is None or key > best_key:
            choice, best_key = AnchorChoice(estimate, refs, ok, checks), key
    return choice


def trust_anchored(
    likelihood: MapLikelihood,
    anchored: PoseEstimate,
    localization: Localization,
    position_prior: PositionPrior | None,
    config: QueryConfig,
) -> tuple[bool, dict[str, int | float], float]:
    """Whether the anchored pose is trusted, the value of each check, and the likelihood at the pose."""
    pose = anchored.pose
    checks: dict[str, int | float] = {
        "inliers": anchored.n_inliers,
        "height_m": round(pose.height_m, 2),
        "pitch_deg": round(anchored.pitch_deg, 2),
    }
    ok = anchored.n_inliers >= config.pnp_min_inliers
    ok &= abs(pose.height_m - 1.6) <= config.max_height_error_m
    ok &= abs(anchored.pitch_deg) <= config.max_pitch_deg
    if position_prior is not None:
        distance = float(position_prior.distances_m(np.array([pose.x_m, pose.y_m]))[0])
        checks["prior_distance_m"] = round(distance, 1)
        ok &= distance <= config.prior_sigmas * position_prior.sigma_m
    lik = likelihood.at(pose.x_m, pose.y_m, pose.yaw_deg)
    best = float(localization.likelihood.max(initial=0.0))
    checks["likelihood"] = round(lik, 4)
    checks["likelihood_best"] = round(best, 4)
    if anchored.n_inliers < config.strong_inliers:
        # Repeated facade elements let a wrong reference pass RANSAC with a few inliers: the map must agree.
        ok &= lik >= config.min_likelihood_ratio * best
    return bool(ok), checks, lik


def _prior_weight(position_prior: PositionPrior | None, estimate: PoseEstimate) -> float:
    if position_prior is None:
        return 1.0
    return float(position_prior.weights(np.array([[estimate.pose.x_m, estimate.pose.y_m]]))[0])
