"""Absolute camera pose from 2D-3D correspondences: PnP + RANSAC, then a refinement with a covariance.

Input: map-frame 3D points (east, north, up; metres) from :mod:`geoloc.localize.anchors` and the pixels where the
photo sees them. Output: a :class:`PoseEstimate` in the conventions of :class:`geoloc.localize.anchors.CameraPose`
(position, height, yaw as local bearing, pitch and roll), the inliers, and the covariance of
(x, y, yaw) from the reprojection residuals.

Robust estimation is OpenCV's USAC (MAGSAC++) on P3P samples; the refinement is Levenberg-Marquardt on
the inliers (``cv2.solvePnPRefineLM``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.anchors import CameraPose

DEFAULT_THRESHOLD_PX = 4.0
DEFAULT_MIN_INLIERS = 12


@dataclass
class PoseEstimate:
    """A camera pose estimated from 2D-3D correspondences (map frame, metres and degrees).

    pose: the camera pose (with its pitch and roll in ``rotation_upright_from_cam``).
    pitch_deg, roll_deg: as in :mod:`geoloc.vision.vanishing` (+ = looking up; + = right side down).
    inliers: (N,) bool over the correspondences. rmse_px: reprojection error of the inliers.
    covariance: (3, 3) covariance of (x_m, y_m, yaw_deg) from the residuals (m^2, m deg, deg^2).
    """

    pose: CameraPose
    pitch_deg: float
    roll_deg: float
    inliers: np.ndarray
    rmse_px: float
    covariance: np.ndarray = field(repr=False)

    @property
    def n_inliers(self) -> int:
        """Number of inlier correspondences."""
        return int(self.inliers.sum())


def _world_from_cam_to_pose(rotation_cam_from_world: np.ndarray, tvec: np.ndarray) -> tuple[CameraPose, float, float]:
    """Pose, pitch and roll from OpenCV's extrinsics (x_cam = R x_world + t)."""
    r = np.asarray(rotation_cam_from_world, dtype=float)
    centre = -r.T @ np.asarray(tvec, dtype=float).reshape(3)
    world_from_cam = r.T
    forward = world_from_cam[:, 2]
    yaw = math.degrees(math.atan2(forward[0], forward[1])) % 360.0
    level = CameraPose(0.0, 0.0, yaw, 0.0).world_from_cam()  # upright frame of this yaw -> world
    upright_from_cam = level.T @ world_from_cam
    down_cam = upright_from_cam[1]  # world-down in the camera frame
    pitch = math.degrees(math.asin(float(np.clip(-down_cam[2], -1.0, 1.0))))
    roll = math.degrees(math.atan2(float(down_cam[0]), float(down_cam[1])))
    pose = CameraPose(float(centre[0]), float(centre[1]), yaw, float(centre[2]), upright_from_cam)
    return pose, pitch, roll


def project(points_xyz: np.ndarray, pose: CameraPose, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of map-frame points (N, 3) seen from ``pose``, and their depth along the optical axis (N,)."""
    cam = (np.asarray(points_xyz, dtype=float) - pose.position) @ pose.world_from_cam()
    depth = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics.cx + intrinsics.focal_px * cam[:, 0] / depth
        v = intrinsics.cy + intrinsics.focal_px * cam[:, 1] / depth
    return np.column_stack([u, v]), depth


def _residuals(
    params: np.ndarray,
    rotation_tail: np.ndarray | None,
    points: np.ndarray,
    pixels: np.ndarray,
    intrinsics: Intrinsics,
    height_m: float,
) -> np.ndarray:
    pose = CameraPose(params[0], params[1], params[2], height_m, rotation_tail)
    projected, _ = project(points, pose, intrinsics)
    residuals: np.ndarray = (projected - pixels).ravel()
    return residuals


def pose_covariance(
    pose: CameraPose, points_xyz: np.ndarray, xy_px: np.ndarray, intrinsics: Intrinsics, sigma_px: float
) -> np.ndarray:
    """(3, 3) covariance of (x_m, y_m, yaw_deg) for pixel noise ``sigma_px`` (Gauss-Newton, numeric Jacobian)."""
    params = np.array([pose.x_m, pose.y_m, pose.yaw_deg])
    steps = np.array([0.01, 0.01, 0.01])
    cols = []
    for i in range(3):
        delta = np.zeros(3)
        delta[i] = steps[i]
        plus = _residuals(params + delta, pose.rotation_upright_from_cam, points_xyz, xy_px, intrinsics, pose.height_m)
        minus = _residuals(params - delta, pose.rotation_upright_from_cam, points_xyz, xy_px, intrinsics, pose.height_m)
        cols.append((plus - minus) / (2.0 * steps[i]))
    jac = np.column_stack(cols)
    info = jac.T @ jac
    try:
        return sigma_px**2 * np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.full((3, 3), np.inf)


def _refit(
    pts: np.ndarray,
    px: np.ndarray,
    intrinsics: Intrinsics,
    rvec: np.ndarray,
    tvec: np.ndarray,
    threshold_px: float,
    min_inliers: int,
) -> PoseEstimate | None:
    """LM refinement on the correspondences within ``threshold_px`` of a pose (twice: inliers may grow)."""
    k = intrinsics.matrix
    for _ in range(2):
        projected, _ = cv2.projectPoints(pts, rvec, tvec, k, None)
        err = np.linalg.norm(projected.reshape(-1, 2) - px, axis=1)
        mask = err <= threshold_px
        if mask.sum() < max(4, min_inliers):
            return None
        rvec, tvec = cv2.solvePnPRefineLM(pts[mask], px[mask], k, None, rvec, tvec)
    rotation, _ = cv2.Rodrigues(rvec)
    pose, pitch, roll = _world_from_cam_to_pose(rotation, tvec)
    projected, depth = project(pts, pose, intrinsics)
    err = np.linalg.norm(projected - px, axis=1)
    mask = (depth > 0) & (err <= threshold_px)
    if mask.sum() < min_inliers:
        return None
    rmse = float(np.sqrt(np.mean(err[mask] ** 2)))
    cov = pose_covariance(pose, pts[mask], px[mask], intrinsics, max(rmse, 0.5))
    return PoseEstimate(pose, pitch, roll, mask, rmse, cov)


Proposal = tuple[np.ndarray, np.ndarray]
"""A RANSAC pose as OpenCV's (rvec, tvec)."""


def group_proposal(
    points_xyz: np.ndarray,
    xy_px: np.ndarray,
    intrinsics: Intrinsics,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    confidence: float = 0.9999,
    max_iters: int = 2000,
) -> Proposal | None:
    """One group's own RANSAC pose (PnP, USAC MAGSAC++), or None (fewer than 6 points, or no pose with 4 inliers).

    Deterministic for given inputs (OpenCV's USAC seeds its sampler per call), so a group that two estimates
    share needs to be solved once (:func:`estimate_pose_from_groups`' ``proposals``).
    """
    group_pts = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    group_px = np.asarray(xy_px, np.float64).reshape(-1, 2)
    if len(group_pts) < 6:
        return None
    found = _pnp_ransac(group_pts, group_px, intrinsics, threshold_px, confidence, max_iters)
    if found is None or found[2] < 4:
        return None
    return found[0], found[1]


def _pnp_ransac(
    pts: np.ndarray, px: np.ndarray, intrinsics: Intrinsics, threshold_px: float, confidence: float, max_iters: int
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """OpenCV's PnP RANSAC (USAC MAGSAC++) on float64 (N, 3) points and (N, 2) pixels: (rvec, tvec, inliers)."""
    try:
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            pts,
            px,
            intrinsics.matrix,
            None,
            iterationsCount=max_iters,
            reprojectionError=threshold_px,
            confidence=confidence,
            flags=cv2.USAC_MAGSAC,
        )
    except cv2.error:
        return None
    if not ok or inliers is None:
        return None
    return rvec, tvec, len(inliers)


def estimate_pose_from_groups(
    groups: list[tuple[np.ndarray, np.ndarray]],
    intrinsics: Intrinsics,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_inliers: int = DEFAULT_MIN_INLIERS,
    confidence: float = 0.9999,
    max_iters: int = 2000,
    proposals: list[Proposal | None] | None = None,
) -> tuple[PoseEstimate | None, np.ndarray]:
    """Pose from several groups of correspondences (one per reference photo): (estimate, group of each point).

    Pooling every group into one RANSAC drowns the few right matches of a good reference among the wrong
    ones of the others; here each group proposes its own RANSAC pose (:func:`group_proposal`), every proposal
    is scored on all the correspondences, and the best is refined on all its inliers.
    groups: [(points (N_i, 3), pixels (N_i, 2))]. proposals: each group's :func:`group_proposal` when the
    caller already has them (same arguments), else they are computed here.
    """
    groups = [(np.asarray(a, np.float64).reshape(-1, 3), np.asarray(b, np.float64).reshape(-1, 2)) for a, b in groups]
    owner = np.concatenate([np.full(len(a), i) for i, (a, _) in enumerate(groups)]) if groups else np.zeros(0, int)
    if len(owner) < max(4, min_inliers):
        return None, owner
    pts = np.concatenate([a for a, _ in groups])
    px = np.concatenate([b for _, b in groups])
    k = intrinsics.matrix
    if proposals is None:
        proposals = [
            group_proposal(a, b, intrinsics, threshold_px=threshold_px, confidence=confidence, max_iters=max_iters)
            for a, b in groups
        ]
    best: tuple[int, np.ndarray, np.ndarray] | None = None
    for proposal in proposals:
        if proposal is None:
            continue
        rvec, tvec = proposal
        projected, _ = cv2.projectPoints(pts, rvec, tvec, k, None)
        support = int((np.linalg.norm(projected.reshape(-1, 2) - px, axis=1) <= threshold_px).sum())
        if best is None or support > best[0]:
            best = (support, rvec, tvec)
    if best is None or best[0] < min_inliers:
        return None, owner
    return _refit(pts, px, intrinsics, best[1], best[2], threshold_px, min_inliers), owner


def estimate_pose(
    points_xyz: np.ndarray,
    xy_px: np.ndarray,
    intrinsics: Intrinsics,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_inliers: int = DEFAULT_MIN_INLIERS,
    confidence: float = 0.9999,
    max_iters: int = 5000,
) -> PoseEstimate | None:
    """Camera pose from N map-frame points (N, 3) seen at pixels (N, 2); None when RANSAC finds too few inliers.

    threshold_px: inlier reprojection error (pixels of the image ``intrinsics`` describes).
    """
    pts = np.ascontiguousarray(points_xyz, dtype=np.float64).reshape(-1, 3)
    px = np.ascontiguousarray(xy_px, dtype=np.float64).reshape(-1, 2)
    n = len(pts)
    if n < max(4, min_inliers):
        return None
    found = _pnp_ransac(pts, px, intrinsics, threshold_px, confidence, max_iters)
    if found is None or found[2] < min_inliers:
        return None
    rvec, tvec, _ = found
    return _refit(pts, px, intrinsics, rvec, tvec, threshold_px, min_inliers)
