"""The motion between two frames of a walk from their own matches alone: rotation and direction of travel.

Frames a few metres apart see the same facades, so their verified matches fix the relative rotation and the
direction of the second camera's centre seen from the first (OpenCV's essential matrix, USAC, then
``recoverPose``), with no map and no answer of either frame: what the map-anchored edges
(:mod:`geoloc.localize.sequence.relative`) cannot give when a frame's own answer is wrong. The distance is not
observed (an essential matrix has no scale): the placement's factor (:func:`motion_factor_covariance`) takes a
nominal step with a loose sigma along the direction and a tight one across it. Camera axes: x right, y down,
z forward; upright axes the same without pitch or roll (``rotation_upright_from_cam``,
:mod:`geoloc.localize.anchors`); yaws are local bearings (deg, clockwise from grid north).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.matching import match_features
from geoloc.vision.features import Features

DEFAULT_THRESHOLD_PX = 1.5
"""The essential matrix's RANSAC threshold (pixels of the first frame's working image)."""
DEFAULT_MIN_INLIERS = 40
"""Fewest essential-matrix inliers for a motion to be kept."""
DEFAULT_RATIO = 0.85
"""Lowe's ratio for the two frames' matches."""


@dataclass(frozen=True)
class TwoViewMotion:
    """The target frame's motion in the source frame's upright axes, from their matches alone.

    forward, left: the unit horizontal direction of the target's centre seen from the source (forward: along
    the source's optical axis; left: to its left). turn_deg: the target's yaw minus the source's (deg,
    clockwise +, in [-180, 180)). n_inliers: essential-matrix inliers. source, target: the frames' indices.
    """

    source: int
    target: int
    forward: float
    left: float
    turn_deg: float
    n_inliers: int


def _rays(features: Features, intrinsics: Intrinsics, index: np.ndarray) -> np.ndarray:
    """(K, 2) normalised image coordinates of the keypoints ``index`` (input pixels through K^-1)."""
    xy = features.xy[index].astype(np.float64)
    return np.column_stack(
        [(xy[:, 0] - intrinsics.cx) / intrinsics.focal_px, (xy[:, 1] - intrinsics.cy) / intrinsics.focal_px]
    )


@dataclass(frozen=True)
class TwoViewFrame:
    """One frame of a two-view motion: its index, local features, camera and (3, 3) ``rotation_upright_from_cam``."""

    index: int
    features: Features
    intrinsics: Intrinsics
    upright: np.ndarray


def two_view_motion(
    source_frame: TwoViewFrame,
    target_frame: TwoViewFrame,
    *,
    ratio: float = DEFAULT_RATIO,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_inliers: int = DEFAULT_MIN_INLIERS,
) -> TwoViewMotion | None:
    """The target's motion relative to the source (module docstring), or None with too few inliers."""
    source, source_features, source_intrinsics = source_frame.index, source_frame.features, source_frame.intrinsics
    target, target_features, target_intrinsics = target_frame.index, target_frame.features, target_frame.intrinsics
    source_upright, target_upright = source_frame.upright, target_frame.upright
    pairs = match_features(target_features, source_features, ratio)
    if len(pairs) < min_inliers:
        return None
    a = _rays(source_features, source_intrinsics, pairs[:, 1])
    b = _rays(target_features, target_intrinsics, pairs[:, 0])
    scale = float(source_features.scale) if source_features.scale else 1.0
    threshold = threshold_px / (source_intrinsics.focal_px * scale)
    essential, mask = cv2.findEssentialMat(a, b, np.eye(3), method=cv2.USAC_MAGSAC, prob=0.999, threshold=threshold)
    if essential is None or essential.shape != (3, 3) or mask is None or int(mask.sum()) < min_inliers:
        return None
    n, rotation, translation, mask = cv2.recoverPose(essential, a, b, np.eye(3), mask=mask.copy())
    if int(n) < min_inliers:
        return None
    # x_target = R x_source + t: the target's centre in the source's camera axes is -R^T t.
    centre = source_upright @ (-rotation.T @ translation.reshape(3))
    horizontal = math.hypot(float(centre[2]), float(centre[0]))
    if horizontal < 1e-6:
        return None
    # The target's forward axis in the source's upright axes.
    axis = source_upright @ rotation.T @ target_upright.T @ np.array([0.0, 0.0, 1.0])
    turn = math.degrees(math.atan2(float(axis[0]), float(axis[2])))
    return TwoViewMotion(
        source,
        target,
        float(centre[2]) / horizontal,
        -float(centre[0]) / horizontal,
        (turn + 180.0) % 360.0 - 180.0,
        int(n),
    )


@dataclass(frozen=True)
class MotionFactor:
    """A relative pose for the placement with its own (3, 3) covariance (gtsam's Pose2 tangent space).

    forward_m, left_m, turn_deg: as :class:`geoloc.localize.sequence.relative.RelativePose`'s.
    """

    source: int
    target: int
    forward_m: float
    left_m: float
    turn_deg: float
    covariance: np.ndarray


def motion_factor(
    motion: TwoViewMotion, step_m: float, along_sigma_m: float, across_sigma_deg: float, turn_sigma_deg: float
) -> MotionFactor:
    """A motion as a relative pose at the nominal distance ``step_m`` with its covariance.

    The covariance is in gtsam's Pose2 between-factor tangent space (the measured pose's own axes: the
    translation rotated by the turn; theta in radians): ``along_sigma_m`` along the direction of travel,
    ``step_m * across_sigma_deg`` (radians) across it, ``turn_sigma_deg`` on the turn.
    """
    forward, left = step_m * motion.forward, step_m * motion.left
    theta = math.radians(-motion.turn_deg)  # gtsam's counter-clockwise angle
    # The direction in the measured pose's axes (rotated by -theta).
    c, s = math.cos(theta), math.sin(theta)
    u = np.array([c * motion.forward + s * motion.left, -s * motion.forward + c * motion.left])
    v = np.array([-u[1], u[0]])
    across = step_m * math.radians(across_sigma_deg)
    covariance = np.zeros((3, 3))
    covariance[:2, :2] = along_sigma_m**2 * np.outer(u, u) + across**2 * np.outer(v, v)
    covariance[2, 2] = math.radians(turn_sigma_deg) ** 2
    return MotionFactor(motion.source, motion.target, forward, left, motion.turn_deg, covariance)
