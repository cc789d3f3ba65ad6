"""Render a perspective street photo of a :class:`~geoloc.sim.scene.Scene`, with per-pixel ground truth.

Geometry (all vectorised numpy; loops only over a few depth layers, buildings and occluders):

1. The camera is first rendered *upright* (optical axis horizontal, no roll) on a canvas that is
   large enough to hold the requested image after rotation. Pitch and roll are then applied as the
   rotation homography ``H = K R K_up^-1`` (a pure rotation about the camera centre), so lines stay
   straight and vanishing points stay true (:mod:`geoloc.sim.pose`).
2. Per canvas column one ray is cast at bearing ``yaw + alpha`` (``alpha`` the column angle). Every
   facing facade hit within range is kept, sorted by distance. A hit at horizontal distance ``s``
   has optical depth ``z = s cos(alpha)`` and spans image rows ``[cy - f (H_b - h) / z, cy + f h / z]``
   (``H_b`` building height, ``h`` camera height). A farther hit is visible only above the top of
   every nearer one, so per column the visible layers have strictly decreasing top rows and a
   pixel shows the first layer whose top is above it (if it is above that layer's bottom).
3. Building pixels get facade coordinates ``u`` (metres along the wall from the facade start) and
   ``v = h - (y - cy) z / f`` (metres above ground) and are textured from the building's look
   (:mod:`geoloc.sim.textures`) with mip levels by pixel footprint (:mod:`geoloc.sim.shading`). Ground
   pixels are intersected with the ground plane (road raster, pavement slabs); the rest is sky
   (gradient + clouds in (bearing, elevation), so the sky agrees between views).
4. Trees (billboards) and parked cars (two boxes with wheels) are drawn far to near with a depth
   test against the building/ground depth buffer (:mod:`geoloc.sim.occluders`).
5. Photometric effects: sun lighting by facade orientation, exposure, vignetting, blur, sensor
   noise. JPEG compression happens when the file is written (:func:`geoloc.photos.exif.write_jpeg`).

Pixel convention: pixel (row r, column c) covers [c, c+1] x [r, r+1]; its centre is (c + 0.5, r + 0.5)
in the coordinates of :class:`~geoloc.core.camera.Intrinsics` (cx = width / 2 is the image centre).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from geoloc.core import labels
from geoloc.core.camera import Intrinsics, wrap_orientation_deg
from geoloc.maps.raycast import cast_all_hits
from geoloc.sim.occluders import CanvasLayers, draw_occluders
from geoloc.sim.pose import Pose, upright_canvas, upright_to_image_homography
from geoloc.sim.scene import Scene
from geoloc.sim.shading import shade_buildings

MAX_RANGE_M = 300.0


@dataclass
class Render:
    """One rendered photo and its ground truth (image size H x W).

    rgb: (H, W, 3) uint8 before JPEG. labels: (H, W) uint8 class codes (:mod:`geoloc.core.labels`).
    building_id: (H, W) int32 building visible at each pixel, -1 where none (trees and cars hide
    buildings). facade_id: (H, W) int32 likewise for facades.
    column_building_id, column_facade_id: (W,) int32 the nearest facade hit of each column's ray
    (what :func:`geoloc.maps.raycast.cast_panoramas` sees along that bearing), -1 where none.
    column_theta_deg: (W,) float32 that facade's orientation relative to the camera
    (normal bearing - yaw, wrapped into [-90, 90)), NaN where none. column_distance_m: (W,) float32
    horizontal distance to it, inf where none. With pitch or roll the per-column values are those
    of the upright camera at the column where the image's centre row maps.
    """

    rgb: np.ndarray
    labels: np.ndarray
    building_id: np.ndarray
    facade_id: np.ndarray
    column_building_id: np.ndarray
    column_facade_id: np.ndarray
    column_theta_deg: np.ndarray
    column_distance_m: np.ndarray
    pose: Pose
    intrinsics: Intrinsics

    def building_shares(self) -> dict[int, float]:
        """Fraction of the image's pixels showing each visible building, largest first."""
        ids = self.building_id[self.building_id >= 0]
        counts = np.bincount(ids) if len(ids) else np.zeros(0)
        total = self.building_id.size
        order = np.argsort(-counts, kind="stable")
        return {int(b): float(counts[b] / total) for b in order if counts[b] > 0}


# ----------------------------------------------------------------------------------------------
# Ray casting per column


@dataclass
class _Layers:
    """Visible facade layers per canvas column, padded to V layers (nearest first).

    top, bottom: (W, V) rows (pad: -inf / -inf); facade, building: (W, V) int (pad -1);
    dist_m (horizontal), depth_m (optical), u_m (along the facade): (W, V); n: (W,) valid layers.
    """

    top: np.ndarray
    bottom: np.ndarray
    facade: np.ndarray
    building: np.ndarray
    dist_m: np.ndarray
    depth_m: np.ndarray
    u_m: np.ndarray
    n: np.ndarray


def _cast_layers(scene: Scene, pose: Pose, canvas: Intrinsics, max_range_m: float) -> _Layers:
    fac = scene.map.facades
    w = canvas.width
    f = canvas.focal_px
    pos = np.array([pose.x_m, pose.y_m])
    alpha = np.arctan((np.arange(w) + 0.5 - canvas.cx) / f)
    bearing = math.radians(pose.yaw_deg) + alpha
    ray_i, fid, dist, u_m = cast_all_hits(
        scene.map, pos, np.degrees(bearing), max_range_m, index=scene.index, min_distance_m=0.05
    )

    bid = fac.building_id[fid].astype(np.int64)
    depth = dist * np.cos(alpha[ray_i])
    h = pose.height_m
    top = canvas.cy - f * (scene.map.building_height_m[bid] - h) / depth
    bottom = canvas.cy + f * h / depth
    n_per = np.bincount(ray_i, minlength=w)
    n_hits = len(ray_i)
    if n_hits == 0:
        empty = np.zeros((w, 1))
        return _Layers(
            empty - np.inf,
            empty - np.inf,
            np.full((w, 1), -1),
            np.full((w, 1), -1),
            empty,
            empty,
            empty,
            np.zeros(w, np.int64),
        )
    rank = np.arange(n_hits) - np.repeat(np.cumsum(n_per) - n_per, n_per)
    pad = np.full((w, int(n_per.max())), np.inf)
    pad[ray_i, rank] = top
    running = np.minimum.accumulate(pad, axis=1)
    prev = np.concatenate([np.full((w, 1), np.inf), running[:, :-1]], axis=1)
    visible = (pad < prev)[ray_i, rank]
    ray_v = ray_i[visible]
    nv = np.bincount(ray_v, minlength=w)
    rank_v = np.arange(len(ray_v)) - np.repeat(np.cumsum(nv) - nv, nv)
    n_layers = int(nv.max())

    def padded(values: np.ndarray, fill: float, dtype: type = np.float64) -> np.ndarray:
        out: np.ndarray = np.full((w, n_layers), fill, dtype=dtype)
        out[ray_v, rank_v] = values[visible]
        return out

    return _Layers(
        padded(top, -np.inf),
        padded(bottom, -np.inf),
        padded(fid, -1, np.int64),
        padded(bid, -1, np.int64),
        padded(dist, np.inf),
        padded(depth, np.inf),
        padded(u_m, 0.0),
        nv,
    )


# ----------------------------------------------------------------------------------------------
# The renderer


def render(
    scene: Scene,
    pose: Pose,
    intrinsics: Intrinsics,
    *,
    seed: int = 0,
    photometric: bool = True,
    occluders: bool = True,
    max_range_m: float = MAX_RANGE_M,
) -> Render:
    """Render ``scene`` from ``pose`` with ``intrinsics``; see the module docstring.

    seed: per-image randomness (exposure, noise). photometric: False gives a clean image (no
    exposure jitter, vignetting, blur or noise) for geometry tests. occluders: draw trees and cars.
    """
    canvas = upright_canvas(pose, intrinsics)
    wc, hc, f = canvas.width, canvas.height, canvas.focal_px
    layers = _cast_layers(scene, pose, canvas, max_range_m)
    yc = np.arange(hc, dtype=np.float64) + 0.5
    xc = np.arange(wc, dtype=np.float64) + 0.5
    alpha = np.arctan((xc - canvas.cx) / f)

    # Which visible layer covers each pixel.
    n_layers = layers.top.shape[1]
    top32 = layers.top.astype(np.float32)
    y32 = yc.astype(np.float32)[:, None]
    k0 = np.zeros((hc, wc), np.uint8)
    for k in range(n_layers):
        k0 += top32[None, :, k] > y32
    kk = np.minimum(k0, n_layers - 1).astype(np.int64)
    flat_layer = kk + (np.arange(wc) * n_layers)[None, :]
    covered = (k0 < layers.n[None, :]) & (y32 <= layers.bottom.ravel()[flat_layer])

    rgb: np.ndarray = np.zeros((hc, wc, 3), np.float32)
    lab: np.ndarray = np.full((hc, wc), labels.SKY, np.uint8)
    bld = np.full((hc, wc), -1, np.int32)
    fcd = np.full((hc, wc), -1, np.int32)
    zbuf = np.full((hc, wc), np.inf, np.float32)
    sun = scene.sun
    sun_v = sun.vector
    ambient, direct = 0.52, 0.62
    light = (ambient, direct)

    # Buildings.
    pix = np.flatnonzero(covered)
    rr, cc = np.divmod(pix, wc)
    hit = flat_layer.ravel()[pix]
    fid = layers.facade.ravel()[hit]
    bid = layers.building.ravel()[hit]
    depth = layers.depth_m.ravel()[hit].astype(np.float32)
    v_m = np.float32(pose.height_m) - (y32[rr, 0] - np.float32(canvas.cy)) * depth / np.float32(f)
    u_m = layers.u_m.ravel()[hit]
    fac = scene.map.facades
    normal = fac.normal[fid].astype(np.float32)
    bearings = math.radians(pose.yaw_deg) + alpha
    ray = np.column_stack([np.sin(bearings), np.cos(bearings)]).astype(np.float32)[cc]
    cos_inc = np.abs(np.einsum("nk,nk->n", normal, ray))
    footprint = (depth / np.float32(f)) / np.sqrt(np.maximum(cos_inc, np.float32(0.2)))
    colour = shade_buildings(scene, bid, fid, u_m, v_m, footprint)
    lam = np.maximum(0.0, normal @ sun_v[:2].astype(np.float32))
    warm = np.array([1.0, 0.96, 0.88], np.float32)
    cool = np.array([0.88, 0.92, 1.0], np.float32)
    occl = 0.82 + 0.18 * np.clip(v_m / 4.0, 0.0, 1.0)
    colour = colour * ((ambient * cool)[None, :] + (direct * lam)[:, None] * warm[None, :]) * occl[:, None]
    rgb.reshape(-1, 3)[pix] = colour
    lab.ravel()[pix] = labels.BUILDING
    bld.ravel()[pix] = bid
    fcd.ravel()[pix] = fid
    zbuf.ravel()[pix] = depth

    # Ground.
    below = (~covered) & (yc[:, None] > canvas.cy + 0.5)
    gr, gc = np.nonzero(below)
    gz = pose.height_m * f / (yc[gr] - canvas.cy)
    gs = gz / np.cos(alpha[gc])
    gb = math.radians(pose.yaw_deg) + alpha[gc]
    gxy = np.column_stack([pose.x_m + gs * np.sin(gb), pose.y_m + gs * np.cos(gb)])
    cls = scene.road_class(gxy)
    gfoot = gz * gz / (f * pose.height_m)
    fade = np.clip(1.0 - gfoot / 0.25, 0.0, 1.0).astype(np.float32)
    nt = scene.ground_noise
    n_sz = nt.shape[0]
    ni = (np.floor(gxy / 0.04).astype(np.int64)) % n_sz
    noise = nt[ni[:, 1], ni[:, 0]] * fade
    ci = np.floor(gxy / 0.8).astype(np.int64) % n_sz
    coarse = nt[ci[:, 1], ci[:, 0]]
    asphalt = np.array([0.30, 0.30, 0.31], np.float32)
    paving = np.array([0.58, 0.56, 0.53], np.float32)
    kerb = np.array([0.66, 0.66, 0.64], np.float32)
    base = np.where((cls == 1)[:, None], asphalt, np.where((cls == 2)[:, None], kerb, paving))
    g = base * (1.0 + 0.35 * noise[:, None] + 0.08 * coarse[:, None])
    slab = 0.6
    frac = (gxy / slab) % 1.0
    joint = (np.minimum(frac, 1.0 - frac) < 0.035).any(axis=1) & (cls == 0)
    g[joint] *= (1.0 - 0.25 * fade[joint])[:, None]
    g *= ambient * 0.9 + direct * max(0.0, sun_v[2])
    rgb[gr, gc] = g
    lab[gr, gc] = labels.ROAD
    zbuf[gr, gc] = gz

    # Sky (whole canvas, then masked).
    sky = ~covered & ~below
    sr, sc = np.nonzero(sky)
    if len(sr):
        ex = (xc[sc] - canvas.cx) / f
        ey = (yc[sr] - canvas.cy) / f
        elev = np.degrees(np.arctan2(-ey, np.sqrt(1.0 + ex * ex)))
        bear = (pose.yaw_deg + np.degrees(alpha[sc])) % 360.0
        clouds = scene.clouds
        res = 90.0 / clouds.shape[0]
        ci = np.clip((np.maximum(elev, 0.0) / res).astype(np.int64), 0, clouds.shape[0] - 1)
        cj = (bear / res).astype(np.int64) % clouds.shape[1]
        op = clouds[ci, cj][:, None]
        t = np.clip(elev / 50.0, 0.0, 1.0)[:, None] ** 0.6
        horizon = np.array([0.80, 0.86, 0.92]) + scene.sky_tint
        zenith = np.array([0.32, 0.52, 0.82]) + scene.sky_tint
        sky_rgb = horizon * (1 - t) + zenith * t
        dsun = np.cos(np.radians(bear - sun.azimuth_deg)) * np.cos(np.radians(elev - sun.elevation_deg))
        sky_rgb = sky_rgb + 0.12 * np.clip(dsun, 0, 1)[:, None] ** 8
        cloud_rgb = np.array([0.95, 0.95, 0.96]) * (0.78 + 0.22 * op)
        rgb[sr, sc] = (sky_rgb * (1 - op * 0.95) + cloud_rgb * op * 0.95).astype(np.float32)

    # Occluders, far to near.
    if occluders:
        draw_occluders(scene, pose, canvas, CanvasLayers(rgb, lab, bld, fcd, zbuf), light)

    # Per-column ground truth of the upright canvas.
    first = layers.n > 0
    col_fid = np.where(first, layers.facade[:, 0], -1).astype(np.int32)
    col_bid = np.where(first, layers.building[:, 0], -1).astype(np.int32)
    col_dist = np.where(first, layers.dist_m[:, 0], np.inf).astype(np.float32)
    nb = fac.normal_bearing_deg[np.maximum(col_fid, 0)]
    col_theta = np.where(first, wrap_orientation_deg(nb - pose.yaw_deg), np.nan).astype(np.float32)

    if canvas is not intrinsics:
        hmat = upright_to_image_homography(pose, intrinsics, canvas)
        shift = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])
        hcv = shift @ hmat @ np.linalg.inv(shift)
        size = (intrinsics.width, intrinsics.height)
        rgb = cv2.warpPerspective(rgb, hcv, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        lab = cv2.warpPerspective(lab, hcv, size, flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        bld = _warp_int(bld, hcv, size)
        fcd = _warp_int(fcd, hcv, size)
        centre = np.vstack(
            [np.arange(intrinsics.width) + 0.5, np.full(intrinsics.width, intrinsics.cy), np.ones(intrinsics.width)]
        )
        back = np.linalg.inv(hmat) @ centre
        src_col = np.clip(np.floor(back[0] / back[2]).astype(np.int64), 0, wc - 1)
        col_fid, col_bid = col_fid[src_col], col_bid[src_col]
        col_dist, col_theta = col_dist[src_col], col_theta[src_col]

    rng = np.random.default_rng([int(seed), 99])
    if photometric:
        rgb = _photometric(rng, rgb)
    out = np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return Render(out, lab, bld, fcd, col_bid, col_fid, col_theta, col_dist, pose, intrinsics)


def _warp_int(img: np.ndarray, hcv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour warp of an int32 id map (ids up to 2**24 kept exact via float32)."""
    warped = cv2.warpPerspective(
        img.astype(np.float32), hcv, size, flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE
    )
    return np.round(warped).astype(np.int32)


def _photometric(rng: np.random.Generator, rgb: np.ndarray) -> np.ndarray:
    """Exposure and white balance jitter, vignetting, slight blur, sensor noise (float RGB in [0, 1])."""
    h, w = rgb.shape[:2]
    gain = (rng.uniform(0.9, 1.1) * (1.0 + rng.normal(0, 0.02, 3))).astype(np.float32)
    img: np.ndarray = rgb * (_vignette(h, w) * gain)
    img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.5, 0.8)))
    noise = rng.standard_normal((h, w, 3), dtype=np.float32)
    noise *= np.float32(0.006)
    noise += rng.standard_normal((h, w, 1), dtype=np.float32) * np.float32(0.011)
    return img + noise


@lru_cache(maxsize=8)
def _vignette(h: int, w: int) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (w / 2)) ** 2
    vignette: np.ndarray = (1.0 - 0.18 * r2)[..., None].astype(np.float32)
    return vignette
