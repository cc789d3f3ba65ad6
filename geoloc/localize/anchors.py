"""Map-anchored 3D points: a labelled photo's keypoints back-projected onto the map's extruded facades.

A reference photo with a known pose sees the map's buildings. The viewing ray of each of its keypoints
meets the first extruded facade (a vertical wall segment from the ground up to its building's height)
that it reaches; that hit is the keypoint's 3D point in the map frame. Later, a query that matches the
keypoint gets a 2D-3D correspondence (:mod:`geoloc.localize.absolute_pose`).

Frames: the map frame is east ``x``, north ``y``, up ``z`` (metres, ground at ``z = 0``). A camera pose
is its position ``(x_m, y_m)``, height above the ground ``height_m``, yaw (local bearing of the
optical axis, degrees clockwise from north) and ``rotation_upright_from_cam`` (3, 3): the rotation
from the camera frame (x right, y down, z forward) to its upright frame (same yaw, no pitch or roll),
as estimated from the vertical vanishing point (:mod:`geoloc.vision.vanishing`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.maps import CityMap
from geoloc.maps.raycast import FacadeIndex

DEFAULT_MAX_RANGE_M = 150.0
"""Keypoints whose ray meets no facade within this horizontal distance get no 3D point."""

HEIGHT_TOLERANCE_M = 0.5
"""A ray may pass this far above a facade's top (roof edges) and still hit it."""


@dataclass(frozen=True)
class CameraPose:
    """A camera pose in a map's local frame.

    x_m, y_m: position (east, north, metres); height_m: above the ground; yaw_deg: local bearing of the
    optical axis (deg clockwise from north); rotation_upright_from_cam: (3, 3) camera -> upright frame
    (pitch and roll; identity for a level camera).
    """

    x_m: float
    y_m: float
    yaw_deg: float
    height_m: float = 1.6
    rotation_upright_from_cam: np.ndarray | None = None

    @property
    def position(self) -> np.ndarray:
        """(3,) camera centre in the map frame (metres)."""
        return np.array([self.x_m, self.y_m, self.height_m])

    def world_from_cam(self) -> np.ndarray:
        """(3, 3) rotation taking camera-frame directions to the map frame (east, north, up)."""
        yaw = np.radians(self.yaw_deg)
        right = [np.cos(yaw), -np.sin(yaw), 0.0]
        down = [0.0, 0.0, -1.0]
        forward = [np.sin(yaw), np.cos(yaw), 0.0]
        world_from_upright = np.column_stack([right, down, forward])
        upright = np.eye(3) if self.rotation_upright_from_cam is None else self.rotation_upright_from_cam
        rotation: np.ndarray = world_from_upright @ upright
        return rotation


@dataclass
class MapAnchors:
    """3D points of keypoints on the map's facades.

    xyz: (N, 3) map-frame points (metres; NaN where ``valid`` is False). facade_id, building_id: (N,)
    int64 (-1 where not valid). distance_m: (N,) horizontal distance from the camera (NaN if not valid).
    """

    xyz: np.ndarray
    facade_id: np.ndarray
    building_id: np.ndarray
    distance_m: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(N,) bool: the keypoint has a 3D point."""
        return self.facade_id >= 0

    def to_arrays(self, prefix: str = "anchor") -> dict[str, np.ndarray]:
        """Plain arrays for storage, named ``<prefix>_xyz`` etc."""
        return {
            f"{prefix}_xyz": self.xyz.astype(np.float32),
            f"{prefix}_facade_id": self.facade_id.astype(np.int32),
            f"{prefix}_building_id": self.building_id.astype(np.int32),
            f"{prefix}_distance_m": self.distance_m.astype(np.float32),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str = "anchor") -> MapAnchors:
        """Inverse of :meth:`to_arrays`."""
        return cls(
            np.asarray(arrays[f"{prefix}_xyz"], np.float64),
            np.asarray(arrays[f"{prefix}_facade_id"], np.int64),
            np.asarray(arrays[f"{prefix}_building_id"], np.int64),
            np.asarray(arrays[f"{prefix}_distance_m"], np.float64),
        )


def pixel_rays(xy_px: np.ndarray, intrinsics: Intrinsics, pose: CameraPose) -> np.ndarray:
    """(N, 3) unit map-frame directions of the viewing rays through pixels ``xy_px`` (N, 2)."""
    xy = np.asarray(xy_px, dtype=float).reshape(-1, 2)
    cam = np.column_stack(
        [(xy[:, 0] - intrinsics.cx) / intrinsics.focal_px, (xy[:, 1] - intrinsics.cy) / intrinsics.focal_px]
    )
    cam = np.column_stack([cam, np.ones(len(cam))])
    rays = cam @ pose.world_from_cam().T
    unit: np.ndarray = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    return unit


def anchor_keypoints(
    city_map: CityMap,
    pose: CameraPose,
    intrinsics: Intrinsics,
    xy_px: np.ndarray,
    *,
    max_range_m: float = DEFAULT_MAX_RANGE_M,
    index: FacadeIndex | None = None,
) -> MapAnchors:
    """3D points of the keypoints at pixels ``xy_px`` (N, 2) of a photo taken from ``pose``.

    Each ray is intersected with every facing facade near the camera; the hit kept is the nearest one
    whose height at the hit lies between the ground and the building's top (plus
    :data:`HEIGHT_TOLERANCE_M`): a ray passing over a low building reaches the taller one behind, as
    the renderer and the eye see it. Rays that point above the horizon of every facade they cross, or
    meet nothing within ``max_range_m``, get no point.
    """
    rays = pixel_rays(xy_px, intrinsics, pose)
    n = len(rays)
    xyz = np.full((n, 3), np.nan)
    facade_out = np.full(n, -1, np.int64)
    building_out = np.full(n, -1, np.int64)
    distance_out = np.full(n, np.nan)
    facades = city_map.facades
    origin = np.array([pose.x_m, pose.y_m])
    index = index or city_map.facade_index
    near = index.facades_near(origin[None, :], max_range_m)
    if n == 0 or len(near) == 0:
        return MapAnchors(xyz, facade_out, building_out, distance_out)
    a = facades.start[near] - origin
    b = facades.end[near] - origin
    facing = np.einsum("fk,fk->f", -a, facades.normal[near]) > 1e-6
    near, a, b = near[facing], a[facing], b[facing]
    horizontal = np.hypot(rays[:, 0], rays[:, 1])
    usable = horizontal > 1e-6
    direction = rays[:, :2] / np.maximum(horizontal, 1e-12)[:, None]  # (N, 2) unit horizontal
    ab = b - a
    denom = direction[:, None, 0] * ab[None, :, 1] - direction[:, None, 1] * ab[None, :, 0]  # (N, F)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (a[None, :, 0] * ab[None, :, 1] - a[None, :, 1] * ab[None, :, 0]) / denom
        u = (a[None, :, 0] * direction[:, None, 1] - a[None, :, 1] * direction[:, None, 0]) / denom
        z = pose.height_m + s * (rays[:, 2] / horizontal)[:, None]
    top = city_map.building_height_m[facades.building_id[near]][None, :]
    ok = (
        np.isfinite(s)
        & (s > 0.1)
        & (s <= max_range_m)
        & (u >= 0)
        & (u <= 1)
        & (z >= 0)
        & (z <= top + HEIGHT_TOLERANCE_M)
    )
    ok &= usable[:, None]
    s_ok = np.where(ok, s, np.inf)
    nearest = np.argmin(s_ok, axis=1)
    hit = np.isfinite(s_ok[np.arange(n), nearest])
    rows = np.flatnonzero(hit)
    cols = nearest[hit]
    dist = s[rows, cols]
    xyz[rows, 0] = origin[0] + direction[rows, 0] * dist
    xyz[rows, 1] = origin[1] + direction[rows, 1] * dist
    xyz[rows, 2] = np.minimum(z[rows, cols], top[0, cols])
    facade_out[rows] = near[cols]
    building_out[rows] = facades.building_id[near[cols]]
    distance_out[rows] = dist
    return MapAnchors(xyz, facade_out, building_out, distance_out)
