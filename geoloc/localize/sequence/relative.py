"""The relative pose of two frames of a walk, from verified matches on one frame's map-anchored keypoints.

Frames a few metres apart overlap heavily, so their matches are reliable where matches across a street are not.
The target frame's keypoints are matched to the source frame's (RootSIFT, ratio test) and its pose is found by PnP
(:func:`geoloc.localize.absolute_pose.estimate_pose`, OpenCV's USAC) on the source's anchors: the 3D points where
the source's keypoints meet the map's facades seen from the source's labelled pose. A labelled pose that is wrong
along a facade (the usual error, a shift parallel to the wall) moves those points with it, so the target's pose
*relative to the source* stays right and carries metric scale; a wrong heading does not, which the placement's
robust loss absorbs. Poses: local metres and local bearings (deg, clockwise from grid north).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from geoloc.core.camera import Intrinsics
from geoloc.localize.absolute_pose import estimate_pose
from geoloc.localize.anchors import MapAnchors
from geoloc.localize.matching import match_features
from geoloc.vision.features import Features

DEFAULT_RATIO = 0.9
"""Lowe's ratio for matches between frames of one walk (looser than a query's 0.8: PnP verifies them)."""
DEFAULT_MIN_ANCHORED = 12
"""Fewest matches on anchored keypoints worth a PnP."""


@dataclass(frozen=True)
class RelativePose:
    """The target frame's pose in the source frame's.

    forward_m: along the source's optical axis; left_m: to its left; turn_deg: the target's yaw minus the
    source's (deg, clockwise +, wrapped to [-180, 180)).

    source, target: the frames' indices in their sequence; n_inliers: PnP inliers.
    """

    source: int
    target: int
    forward_m: float
    left_m: float
    turn_deg: float
    n_inliers: int

    @property
    def distance_m(self) -> float:
        """Horizontal distance between the two camera centres (m)."""
        return math.hypot(self.forward_m, self.left_m)


def pose_in_frame(
    source_xy: tuple[float, float], source_yaw_deg: float, target_xy: tuple[float, float], target_yaw_deg: float
) -> tuple[float, float, float]:
    """(forward_m, left_m, turn_deg) of a target pose in a source pose's frame (local metres, bearings in deg)."""
    yaw = math.radians(source_yaw_deg)
    dx, dy = target_xy[0] - source_xy[0], target_xy[1] - source_xy[1]
    forward = dx * math.sin(yaw) + dy * math.cos(yaw)
    left = -dx * math.cos(yaw) + dy * math.sin(yaw)
    turn = (target_yaw_deg - source_yaw_deg + 180.0) % 360.0 - 180.0
    return forward, left, turn


def relative_pose(
    source: int,
    target: int,
    source_pose: tuple[float, float, float],
    source_features: Features,
    source_anchors: MapAnchors,
    target_features: Features,
    target_intrinsics: Intrinsics,
    *,
    ratio: float = DEFAULT_RATIO,
    min_anchored: int = DEFAULT_MIN_ANCHORED,
) -> RelativePose | None:
    """The target frame's pose relative to the source's (module docstring), or None when PnP finds none.

    source_pose: the source's labelled (x_m, y_m, yaw_deg), the pose its anchors were cast from.
    """
    pairs = match_features(target_features, source_features, ratio)
    if not len(pairs):
        return None
    valid = source_anchors.valid[pairs[:, 1]]
    if int(valid.sum()) < min_anchored:
        return None
    estimate = estimate_pose(
        source_anchors.xyz[pairs[valid, 1]], target_features.xy[pairs[valid, 0]], target_intrinsics
    )
    if estimate is None:
        return None
    est = estimate.pose
    forward, left, turn = pose_in_frame(
        (source_pose[0], source_pose[1]), source_pose[2], (est.x_m, est.y_m), est.yaw_deg
    )
    return RelativePose(source, target, forward, left, turn, estimate.n_inliers)
