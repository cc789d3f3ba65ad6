"""Fusion and uncertainty: the trusted anchored pose refined on the map, the likelihood's poses, their ranks.

Each pose carries the radius of its 90 % region: from the PnP covariance plus the anchoring references' own
pose uncertainty for an anchored pose, from the posterior's mass around the pose for a likelihood pose.
"""

from __future__ import annotations

import math
from collections.abc import Hashable

import numpy as np

from geoloc.localize.absolute_pose import PoseEstimate
from geoloc.localize.grid import Localization, PositionPrior
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.query.answer import AnswerPose
from geoloc.localize.query.config import CHI2_2D_90, QueryConfig
from geoloc.localize.refinement import RefineOptions, refine_pose
from geoloc.localize.store import StoredReference


def anchored_answer(
    likelihood: MapLikelihood,
    anchored: PoseEstimate,
    anchor_refs: list[Hashable],
    stored: dict[Hashable, StoredReference],
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
        lik = likelihood.at(pose.x_m, pose.y_m, pose.yaw_deg)
        return AnswerPose(1, pose.x_m, pose.y_m, pose.yaw_deg % 360.0, 1.0, radius, "anchors", lik, anchored.n_inliers)
    refined = refine_pose(
        likelihood,
        pose.x_m,
        pose.y_m,
        pose.yaw_deg,
        prior_xy=(pose.x_m, pose.y_m),
        prior_sigma_m=sigma,
        options=RefineOptions(half_size_m=min(6.0, 2.0 * sigma), sharpness=config.sharpness),
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


def likelihood_answers(
    likelihood: MapLikelihood,
    localization: Localization,
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
                likelihood,
                x,
                y,
                yaw,
                prior_weights=None if position_prior is None else position_prior.weights,
                options=RefineOptions(half_size_m=config.cell_m / 2.0 + 1.0, sharpness=config.sharpness),
            )
            x, y, yaw, lik = refined.x_m, refined.y_m, refined.yaw_deg, refined.likelihood
        radius = mass_radius(positions, heat, np.array([x, y]), 0.9, config.cell_m)
        if any(math.hypot(x - a.x_m, y - a.y_m) < config.cell_m / 2.0 for a in already + answers):
            continue
        answers.append(AnswerPose(0, x, y, yaw, float(pose.probability), radius, "likelihood", lik))
    return answers


def mass_radius(positions: np.ndarray, mass: np.ndarray, centre: np.ndarray, share: float, cell_m: float) -> float:
    """Smallest radius around ``centre`` holding ``share`` of the (P,) mass at ``positions`` (plus half a cell)."""
    total = float(mass.sum())
    if total <= 0 or len(positions) == 0:
        return float("inf")
    distance = np.hypot(*(positions - centre).T)
    order = np.argsort(distance)
    cumulative = np.cumsum(mass[order]) / total
    index = int(np.searchsorted(cumulative, share))
    return float(distance[order][min(index, len(order) - 1)] + cell_m / 2.0)


def rank_poses(poses: list[AnswerPose], top_n: int) -> list[AnswerPose]:
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
