"""The geometry of the vanishing-point search: segments, their consistency with a VP, the upright frame.

:mod:`geoloc.vision.vanishing` has the method and the frames' definitions.

Consistency of a segment with a VP direction (:func:`vp_residuals`): let ``u`` be the image line from the
segment's midpoint to the VP (works for VPs at infinity) and ``err`` the angle between the segment and ``u``;
the residual is ``max(d / tol_px, err / max_angle_deg)`` with ``d = L/2 sin(err)`` (inliers: <= 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.vision.lines import segment_lengths_px


@dataclass
class SegmentGeometry:
    """Line segments as the VP search sees them (camera frame x right, y down, z forward)."""

    midpoints: np.ndarray  # (N, 2) px
    unit_dirs: np.ndarray  # (N, 2) image direction, unit
    lengths_px: np.ndarray  # (N,)
    normals_cam: np.ndarray  # (N, 3) unit normals of the interpretation planes (camera frame)
    tilt_from_vertical_deg: np.ndarray  # (N,) image angle between segment and the image y axis


def segment_geometry(segments: np.ndarray, intrinsics: Intrinsics) -> SegmentGeometry:
    """The geometry of (N, 4) ``x1, y1, x2, y2`` px segments of the image described by ``intrinsics``."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    p1, p2 = s[:, :2], s[:, 2:]
    lengths = segment_lengths_px(s)
    dirs = (p2 - p1) / np.maximum(lengths, 1e-9)[:, None]
    k_inv = np.linalg.inv(intrinsics.matrix)
    ones = np.ones((len(s), 1))
    r1 = np.hstack([p1, ones]) @ k_inv.T
    r2 = np.hstack([p2, ones]) @ k_inv.T
    normals = np.cross(r1, r2)
    normals /= np.maximum(np.linalg.norm(normals, axis=1), 1e-12)[:, None]
    tilt = np.degrees(np.arccos(np.clip(np.abs(dirs[:, 1]), 0.0, 1.0)))
    return SegmentGeometry((p1 + p2) / 2.0, dirs, lengths, normals, tilt)


def vp_residuals(
    directions_cam: np.ndarray,
    geo: SegmentGeometry,
    intrinsics: Intrinsics,
    tol_px: float,
    max_angle_deg: float,
) -> np.ndarray:
    """(M, N) normalised consistency residuals of N segments with M VP directions (<= 1: inlier)."""
    v = np.ascontiguousarray(np.atleast_2d(directions_cam) @ intrinsics.matrix.T)  # (M, 3) homogeneous image points
    out = np.empty((len(v), len(geo.lengths_px)))
    _residuals_kernel(
        v,
        np.ascontiguousarray(geo.midpoints, dtype=np.float64),
        np.ascontiguousarray(geo.unit_dirs, dtype=np.float64),
        np.ascontiguousarray(geo.lengths_px, dtype=np.float64),
        float(tol_px),
        float(max_angle_deg),
        out,
    )
    return out


@numba.njit(cache=True, nogil=True)
def _residuals_kernel(
    v: np.ndarray,
    midpoints: np.ndarray,
    unit_dirs: np.ndarray,
    lengths_px: np.ndarray,
    tol_px: float,
    max_angle_deg: float,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled; checked against the numpy form in the tests
    """out[m, n]: the residual of segment n with image point v[m] (module docstring), numpy's operation order.

    One pass per pair instead of numpy's (M, N, 2) temporaries: the horizontal search scores ~900 directions
    against every segment of every photo.
    """
    to_deg = 180.0 / math.pi
    for m in range(v.shape[0]):
        vx, vy, vz = v[m, 0], v[m, 1], v[m, 2]
        for n in range(midpoints.shape[0]):
            ux = vx - midpoints[n, 0] * vz
            uy = vy - midpoints[n, 1] * vz
            norm_u = math.sqrt(ux * ux + uy * uy)
            cross = abs(unit_dirs[n, 0] * uy - unit_dirs[n, 1] * ux)
            sin_err = cross / norm_u if norm_u > 1e-12 else 0.0
            sin_err = min(max(sin_err, 0.0), 1.0)
            dist_px = 0.5 * lengths_px[n] * sin_err
            angle_deg = math.asin(sin_err) * to_deg
            out[m, n] = max(dist_px / tol_px, angle_deg / max_angle_deg)


def inlier_weight(residual: np.ndarray) -> np.ndarray:
    """Soft inlier weight in [0, 1] from a normalised residual (1 at 0, 0 beyond 1)."""
    return np.clip(1.0 - residual**2, 0.0, None)


def smallest_eigenvector(matrix: np.ndarray) -> np.ndarray:
    """The unit eigenvector of the smallest eigenvalue of a symmetric matrix."""
    w, v = np.linalg.eigh(matrix)
    return v[:, np.argmin(w)]


def upright_rotation(down_cam: np.ndarray) -> np.ndarray:
    """(3, 3) rotation from the camera frame to the upright frame given world-down in the camera frame.

    Rows: x' = y' x z', y' = down, z' = optical axis projected on the horizontal plane.
    """
    g = np.asarray(down_cam, dtype=float)
    g = g / np.linalg.norm(g)
    z = np.array([0.0, 0.0, 1.0]) - g[2] * g
    if np.linalg.norm(z) < 1e-9:  # looking straight up or down: any heading
        z = np.array([1.0, 0.0, 0.0]) - g[0] * g
    z /= np.linalg.norm(z)
    x = np.cross(g, z)
    return np.vstack([x, g, z])


def pitch_roll_deg(down_cam: np.ndarray) -> tuple[float, float]:
    """Pitch (+ = looking up) and roll (+ = right side down) in degrees from world-down in the camera frame."""
    g = np.asarray(down_cam, dtype=float)
    g = g / np.linalg.norm(g)
    pitch = math.degrees(math.asin(float(np.clip(-g[2], -1.0, 1.0))))
    roll = math.degrees(math.atan2(float(g[0]), float(g[1])))
    return pitch, roll


def horizontal_direction_cam(theta_deg: np.ndarray | float, rotation_upright_from_cam: np.ndarray) -> np.ndarray:
    """(..., 3) camera-frame direction of the horizontal lines of facades with orientation ``theta_deg``."""
    t = np.radians(np.asarray(theta_deg, dtype=float))
    up = np.stack([np.cos(t), np.zeros_like(t), -np.sin(t)], axis=-1)
    direction: np.ndarray = up @ rotation_upright_from_cam  # R^T applied to row vectors
    return direction


def rotation_upright_from_pitch_roll(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """(3, 3) rotation camera -> upright frame for a camera with this pitch and roll (zero relative yaw).

    Inverse of :func:`pitch_roll_deg`: ``rotation[1]`` is world-down in the camera frame.
    """
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    r_pitch = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(p), math.sin(p)], [0.0, -math.sin(p), math.cos(p)]])
    r_roll = np.array([[math.cos(r), math.sin(r), 0.0], [-math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]])
    rotation: np.ndarray = (r_roll @ r_pitch).T
    return rotation
