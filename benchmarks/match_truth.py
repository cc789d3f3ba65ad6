"""Ground truth for feature matches in a simulated world (used by ``bench_features.py``; not a test).

Local frame: x east, y north, z up (metres); camera x right, y down, z forward; keypoints in OpenCV's
pixel convention (pixel centres at integers). A query pixel on a facade is *co-visible* with a reference
when its 3D point (the true viewing ray cut with the facade's vertical plane) projects into the reference
onto the same facade; a match is *correct* when both keypoints lie on the same facade and that point
reprojects within a tolerance of the reference keypoint (see ``bench_features.py``'s docstring).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.maps import CityMap
from geoloc.sim.pose import Pose, rotation_matrix
from geoloc.sim.world import World


def _camera_axes(pose: Pose) -> np.ndarray:
    """3x3 matrix whose rows are the upright camera's right, down and forward axes in the local frame."""
    yaw = np.radians(pose.yaw_deg)
    return np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [0.0, 0.0, -1.0], [np.sin(yaw), np.cos(yaw), 0.0]])


def viewing_rays(pose: Pose, intr: Intrinsics, xy: np.ndarray) -> np.ndarray:
    """(N, 3) local-frame directions of the rays through keypoints at (N, 2) pixel centres (OpenCV convention)."""
    pix = np.column_stack([xy[:, 0] + 0.5, xy[:, 1] + 0.5, np.ones(len(xy))])
    d_cam = pix @ np.linalg.inv(intr.matrix).T
    d_up = d_cam @ rotation_matrix(pose.pitch_deg, pose.roll_deg)  # R^T d for each row
    return d_up @ _camera_axes(pose)


def project(pose: Pose, intr: Intrinsics, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) keypoint coordinates (OpenCV convention) and (N,) depth of local-frame points (N, 3)."""
    centre = np.array([pose.x_m, pose.y_m, pose.height_m])
    d_up = (points - centre) @ _camera_axes(pose).T
    d_cam = d_up @ rotation_matrix(pose.pitch_deg, pose.roll_deg).T
    z = d_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pix = d_cam @ intr.matrix.T
        uv = pix[:, :2] / pix[:, 2:3] - 0.5
    return uv, z


def filled_facade_ids(facade_id: np.ndarray, radius: int = 2) -> np.ndarray:
    """Facade id per pixel; pixels showing no facade take a facade id found within ``radius`` px (if any)."""
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    near = cv2.dilate((facade_id + 1).astype(np.float32), kernel).astype(np.int64) - 1
    return np.where(facade_id >= 0, facade_id, near)


def _ids_at(ids: np.ndarray, xy: np.ndarray) -> np.ndarray:
    h, w = ids.shape
    return ids[np.clip(np.round(xy[:, 1]).astype(int), 0, h - 1), np.clip(np.round(xy[:, 0]).astype(int), 0, w - 1)]


@dataclass
class GtView:
    """What the correctness check needs of one world image."""

    pose: Pose
    intrinsics: Intrinsics
    facade_ids: np.ndarray  # filled (see filled_facade_ids)


def correct_matches(
    city: CityMap, query: GtView, reference: GtView, q_xy: np.ndarray, r_xy: np.ndarray, tol_px: float
) -> np.ndarray:
    """(K,) bool: which matches are correct.

    A match is correct when both keypoints are on the same facade and the query ray, cut with that
    facade's plane, reprojects into the reference within ``tol_px`` of the reference keypoint.
    """
    if len(q_xy) == 0:
        return np.zeros(0, bool)
    fq = _ids_at(query.facade_ids, q_xy)
    fr = _ids_at(reference.facade_ids, r_xy)
    ok = (fq >= 0) & (fq == fr)
    f = np.maximum(fq, 0)
    fac = city.facades
    rays = viewing_rays(query.pose, query.intrinsics, q_xy)
    centre = np.array([query.pose.x_m, query.pose.y_m, query.pose.height_m])
    normal = fac.normal[f]
    denom = np.einsum("ij,ij->i", rays[:, :2], normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", fac.start[f] - centre[:2], normal) / denom
    ok &= np.isfinite(t) & (t > 0)
    points = centre + np.where(ok, t, 0.0)[:, None] * rays
    uv, depth = project(reference.pose, reference.intrinsics, points)
    err = np.linalg.norm(uv - r_xy, axis=1)
    return ok & (depth > 0) & (err <= tol_px)


def covisible_shares(
    city: CityMap, world: World, query: str, references: list[str], step_px: int = 4
) -> dict[str, float]:
    """Share of the query image whose facade point each reference sees on the same facade.

    Pixels are sampled on a grid of ``step_px`` (see the module docstring).
    """
    fid = world.gt(query)["facade_id"]
    grid = fid[::step_px, ::step_px]
    ys, xs = np.nonzero(grid >= 0)
    xy = np.column_stack([xs * step_px, ys * step_px]).astype(np.float64)
    f = grid[ys, xs]
    q = world.image(query)
    rays = viewing_rays(q.pose, q.intrinsics, xy)
    centre = np.array([q.pose.x_m, q.pose.y_m, q.pose.height_m])
    normal = city.facades.normal[f]
    t = np.einsum("ij,ij->i", city.facades.start[f] - centre[:2], normal) / np.einsum("ij,ij->i", rays[:, :2], normal)
    points = centre + t[:, None] * rays
    out = {}
    for name in references:
        r = world.image(name)
        uv, depth = project(r.pose, r.intrinsics, points)
        h, w = world.gt(name)["facade_id"].shape
        u = np.round(uv).astype(np.int64)
        ok = (depth > 0) & (u[:, 0] >= 0) & (u[:, 0] < w) & (u[:, 1] >= 0) & (u[:, 1] < h)
        same = np.zeros(len(f), bool)
        same[ok] = world.gt(name)["facade_id"][u[ok, 1], u[ok, 0]] == f[ok]
        out[name] = float(same.sum() / grid.size)
    return out


def overlap(world: World, a: str, b: str) -> float:
    """Sum over buildings of the smaller of the two images' pixel shares."""
    sa = {x["building_id"]: x["pixel_share"] for x in world.image(a).record["buildings"]}
    sb = {x["building_id"]: x["pixel_share"] for x in world.image(b).record["buildings"]}
    return float(sum(min(s, sb.get(k, 0.0)) for k, s in sa.items()))
