"""The simulated camera's pose and the upright canvas the renderer draws on before pitch and roll.

The renderer (:mod:`geoloc.sim.render`) first draws an *upright* camera (optical axis horizontal, no
roll) on a canvas large enough to hold the requested image after rotation, then applies pitch and roll
as the rotation homography ``H = K R K_up^-1`` (a pure rotation about the camera centre). This module
holds the pose, that rotation ``R`` and homography ``H``, and the upright canvas's intrinsics.

Frames: the map's local frame (x east, y north, metres); camera x right, y down, z forward. Pixel
convention: pixel (row r, column c) covers [c, c+1] x [r, r+1]; its centre is (c + 0.5, r + 0.5) in the
coordinates of :class:`~geoloc.core.camera.Intrinsics`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from geoloc.core.camera import Intrinsics

CAMERA_HEIGHT_M = 1.6


@dataclass(frozen=True)
class Pose:
    """Camera pose in the map's local frame.

    x_m, y_m: position (east, north, metres); yaw_deg: local bearing of the optical axis (deg
    clockwise from north); pitch_deg: positive looking up; roll_deg: positive when the camera is
    turned clockwise about its optical axis as seen from behind (the horizon then rises to the
    right in the image); height_m: camera height above the ground.
    """

    x_m: float
    y_m: float
    yaw_deg: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    height_m: float = CAMERA_HEIGHT_M

    def as_dict(self) -> dict[str, float]:
        """The pose as a JSON-ready dict (metres, degrees)."""
        return {k: float(v) for k, v in asdict(self).items()}


def rotation_matrix(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """3x3 R taking a direction in the upright camera frame to the actual (pitched, rolled) camera frame."""
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(-p), -math.sin(-p)], [0, math.sin(-p), math.cos(-p)]])
    rz = np.array([[math.cos(-r), -math.sin(-r), 0], [math.sin(-r), math.cos(-r), 0], [0, 0, 1]])
    rotation: np.ndarray = rz @ rx
    return rotation


def upright_to_image_homography(pose: Pose, intrinsics: Intrinsics, upright: Intrinsics) -> np.ndarray:
    """3x3 H mapping upright-canvas pixel coordinates to image pixel coordinates (same pixel convention)."""
    homography: np.ndarray = (
        intrinsics.matrix @ rotation_matrix(pose.pitch_deg, pose.roll_deg) @ np.linalg.inv(upright.matrix)
    )
    return homography


def upright_canvas(pose: Pose, intr: Intrinsics) -> Intrinsics:
    """Intrinsics of the upright canvas that covers the rotated image (the image itself when upright)."""
    if pose.pitch_deg == 0.0 and pose.roll_deg == 0.0:
        return intr
    w, h = intr.width, intr.height
    xs = np.r_[np.linspace(0, w, 9), np.full(9, w), np.linspace(0, w, 9), np.zeros(9)]
    ys = np.r_[np.zeros(9), np.linspace(0, h, 9), np.full(9, h), np.linspace(0, h, 9)]
    pts = np.linalg.inv(intr.matrix) @ np.vstack([xs, ys, np.ones_like(xs)])
    up = rotation_matrix(pose.pitch_deg, pose.roll_deg).T @ pts
    if np.any(up[2] <= 1e-3):
        raise ValueError("pitch/roll too large for the field of view")
    qx = intr.focal_px * up[0] / up[2]
    qy = intr.focal_px * up[1] / up[2]
    x0, x1 = math.floor(qx.min()) - 2, math.ceil(qx.max()) + 2
    y0, y1 = math.floor(qy.min()) - 2, math.ceil(qy.max()) + 2
    return Intrinsics(x1 - x0, y1 - y0, intr.focal_px, float(-x0), float(-y0), "upright_canvas")
