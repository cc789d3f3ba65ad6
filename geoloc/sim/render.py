"""Render a perspective street photo of a :class:`~geoloc.sim.scene.Scene`, with per-pixel ground truth.

Geometry (all vectorised numpy; loops only over a few depth layers, buildings and occluders):

1. The camera is first rendered *upright* (optical axis horizontal, no roll) on a canvas that is
   large enough to hold the requested image after rotation. Pitch and roll are then applied as the
   rotation homography ``H = K R K_up^-1`` (a pure rotation about the camera centre), so lines stay
   straight and vanishing points stay true.
2. Per canvas column one ray is cast at bearing ``yaw + alpha`` (``alpha`` the column angle). Every
   facing facade hit within range is kept, sorted by distance. A hit at horizontal distance ``s``
   has optical depth ``z = s cos(alpha)`` and spans image rows ``[cy - f (H_b - h) / z, cy + f h / z]``
   (``H_b`` building height, ``h`` camera height). A farther hit is visible only above the top of
   every nearer one, so per column the visible layers have strictly decreasing top rows and a
   pixel shows the first layer whose top is above it (if it is above that layer's bottom).
3. Building pixels get facade coordinates ``u`` (metres along the wall from the facade start) and
   ``v = h - (y - cy) z / f`` (metres above ground) and are textured from the building's look
   (:mod:`geoloc.sim.textures`) with mip levels by pixel footprint. Ground pixels are intersected
   with the ground plane (road raster, pavement slabs); the rest is sky (gradient + clouds in
   (bearing, elevation), so the sky agrees between views).
4. Trees (billboards) and parked cars (two boxes with wheels) are drawn far to near with a depth
   test against the building/ground depth buffer.
5. Photometric effects: sun lighting by facade orientation, exposure, vignetting, blur, sensor
   noise. JPEG compression happens when the file is written (:func:`geoloc.photos.exif.write_jpeg`).

Pixel convention: pixel (row r, column c) covers [c, c+1] x [r, r+1]; its centre is (c + 0.5, r + 0.5)
in the coordinates of :class:`~geoloc.core.camera.Intrinsics` (cx = width / 2 is the image centre).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import cv2
import numpy as np
import numpy.typing as npt

from geoloc.core import labels
from geoloc.core.camera import Intrinsics, wrap_orientation_deg
from geoloc.maps.raycast import cast_all_hits
from geoloc.sim.scene import Scene
from geoloc.sim.textures import (
    DETAIL_HEIGHT_M,
    DETAIL_TEXELS_PER_M,
    NOISE_TEXELS_PER_M,
    SIGN_BAND_M,
    TEXELS_PER_M,
)

CAMERA_HEIGHT_M = 1.6
MAX_RANGE_M = 300.0
OCCLUDER_RANGE_M = (2.5, 150.0)  # trees and cars nearer or farther than this are not drawn


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


def _upright_canvas(pose: Pose, intr: Intrinsics) -> Intrinsics:
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
# Texture sampling


def _bilinear(tex: np.ndarray, var: np.ndarray, fx: np.ndarray, fy: np.ndarray, wrap_y: bool) -> np.ndarray:
    """Bilinear lookup in (K, h, w, 3) uint8 ``tex`` at texel coords (fx, fy) (centres at i + 0.5); x wraps."""
    _, th, tw, _ = tex.shape
    x = fx - 0.5
    y = fy - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    ax = (x - x0)[:, None].astype(np.float32)
    ay = (y - y0)[:, None].astype(np.float32)
    x0 = x0.astype(np.int64) % tw
    x1 = (x0 + 1) % tw
    y0 = y0.astype(np.int64)
    y1 = y0 + 1
    if wrap_y:
        y0 %= th
        y1 %= th
    else:
        y0 = np.clip(y0, 0, th - 1)
        y1 = np.clip(y1, 0, th - 1)
    flat = tex.reshape(-1, 3)
    base = var.astype(np.int64) * (th * tw)
    c00 = flat[base + y0 * tw + x0].astype(np.float32)
    c01 = flat[base + y0 * tw + x1].astype(np.float32)
    c10 = flat[base + y1 * tw + x0].astype(np.float32)
    c11 = flat[base + y1 * tw + x1].astype(np.float32)
    top = c00 + (c01 - c00) * ax
    bot = c10 + (c11 - c10) * ax
    colour: np.ndarray = (top + (bot - top) * ay) * np.float32(1.0 / 255.0)
    return colour


def _sample_mip(
    levels: list[np.ndarray],
    level: np.ndarray,
    var: np.ndarray,
    fx0: np.ndarray,
    fy0: np.ndarray,
    wrap_y: bool,
    fractional: bool,
) -> np.ndarray:
    """Sample a mip list per pixel at its ``level``.

    fractional: (fx0, fy0) are fractions of the tile in [0, 1); else texel coords at level 0.
    """
    out = np.empty((len(level), 3), np.float32)
    for lv in np.unique(level):
        sel = level == lv
        tex = levels[int(lv)]
        th, tw = tex.shape[-3:-1]
        if fractional:
            fx, fy = fx0[sel] * tw, fy0[sel] * th
        else:
            scale = tw / levels[0].shape[-2]
            fx, fy = fx0[sel] * scale, fy0[sel] * (th / levels[0].shape[-3])
        tex4 = tex if tex.ndim == 4 else tex[None]
        out[sel] = _bilinear(tex4, var[sel], fx, fy, wrap_y)
    return out


def _hash(*keys: npt.ArrayLike) -> np.ndarray:
    """Deterministic integer hash of integer arrays -> uint64."""
    h = np.full(np.broadcast(*keys).shape, 1469598103934665603, dtype=np.uint64)
    for k in keys:
        h ^= np.asarray(k).astype(np.uint64)
        h *= np.uint64(1099511628211)
        h ^= h >> np.uint64(29)
    return h


def _shade_buildings(
    scene: Scene,
    bid: np.ndarray,
    fid: np.ndarray,
    u_m: np.ndarray,
    v_m: np.ndarray,
    footprint_m: np.ndarray,
) -> np.ndarray:
    """(N, 3) float32 RGB of building pixels from their facade coordinates (u along, v up, metres)."""
    fac = scene.map.facades
    out = np.empty((len(bid), 3), np.float32)
    d = TEXELS_PER_M
    level_all = np.clip(np.floor(np.log2(np.maximum(footprint_m * d, 1e-6)) + 0.5), 0, 3).astype(np.int64)
    order = np.argsort(bid, kind="stable")
    bounds = np.flatnonzero(np.diff(bid[order])) + 1
    for idx in np.split(order, bounds):
        if len(idx) == 0:
            continue
        b = int(bid[idx[0]])
        look = scene.look(b)
        f, u, v, level = fid[idx], u_m[idx], v_m[idx], level_all[idx]
        length = fac.length_m[f]
        n_bays = np.maximum(np.round(length / look.bay_m), 1)
        plain = length < 0.8 * look.bay_m
        bay = length / n_bays
        fu = (u / bay) % 1.0
        bay_i = np.floor(u / bay).astype(np.int64)
        rgb = np.broadcast_to(look.wall_rgb.astype(np.float32), (len(idx), 3)).copy()
        top_of_floors = look.ground_m + look.n_floors * look.floor_m
        ground = (v < look.ground_m) & ~plain
        upper = (v >= look.ground_m) & (v < top_of_floors) & ~plain
        if ground.any():
            g = _hash(np.int64(scene.seed), np.int64(b), f[ground], bay_i[ground]) % np.uint64(10)
            var = np.where(g < 7, 0, np.where(g < 9, 1, 2)) if look.shops else np.where(g < 3, 1, 2)
            rgb[ground] = _sample_mip(
                look.ground, level[ground], var, fu[ground], 1.0 - v[ground] / look.ground_m, False, True
            )
        if upper.any():
            fl = (v[upper] - look.ground_m) / look.floor_m
            fl_i = np.floor(fl).astype(np.int64)
            g = _hash(np.int64(scene.seed), np.int64(b), f[upper], bay_i[upper], fl_i) % np.uint64(10)
            var = np.where(g < 5, 0, np.where(g < 7, 1, np.where(g < 9, 2, 3)))
            rgb[upper] = _sample_mip(look.tiles, level[upper], var, fu[upper], 1.0 - (fl - fl_i), True, True)
        # Cornice at the top of the wall.
        cornice = v > scene.map.building_height_m[b] - 0.35
        rgb[cornice] = look.trim_rgb
        under = (v > scene.map.building_height_m[b] - 0.5) & ~cornice
        rgb[under] *= 0.6
        # Shop signs on the ground floor's sign band.
        u_ring = scene.facade_offset_m[f] + u
        band = (v >= SIGN_BAND_M[0]) & (v < SIGN_BAND_M[1]) & ~plain
        if band.any() and look.sign_mask.any():
            sx = np.clip((u_ring[band] * d).astype(np.int64), 0, len(look.sign_mask) - 1)
            on = look.sign_mask[sx]
            if on.any():
                sel = np.flatnonzero(band)[on]
                rgb[sel] = _sample_mip(
                    look.sign,
                    level[sel],
                    np.zeros(len(sel), np.int64),
                    u_ring[sel] * d,
                    (SIGN_BAND_M[1] - v[sel]) * d,
                    False,
                    False,
                )
        # Stains and large-scale variation, continuous around the building.
        nh, nw = look.stain.shape
        sy = np.clip((v * NOISE_TEXELS_PER_M).astype(np.int64), 0, nh - 1)
        sx = np.clip((u_ring * NOISE_TEXELS_PER_M).astype(np.int64), 0, nw - 1)
        rgb *= look.stain[sy, sx][:, None]
        low = np.flatnonzero((v < DETAIL_HEIGHT_M) & (level < 3))
        if len(low):
            dh, dw = look.detail.shape
            dy = np.clip((v[low] * DETAIL_TEXELS_PER_M).astype(np.int64), 0, dh - 1)
            dx = np.clip((u_ring[low] * DETAIL_TEXELS_PER_M).astype(np.int64), 0, dw - 1)
            rgb[low] *= (look.detail[dy, dx] * np.float32(1.0 / 128.0))[:, None]
        out[idx] = rgb
    return out


# ----------------------------------------------------------------------------------------------
# Occluders


def _project(points_enu: np.ndarray, pose: Pose, canvas: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) local (east, north, up) points -> (N, 2) upright-canvas pixel coords and (N,) optical depth."""
    yaw = math.radians(pose.yaw_deg)
    fwd = np.array([math.sin(yaw), math.cos(yaw)])
    right = np.array([math.cos(yaw), -math.sin(yaw)])
    rel = points_enu[:, :2] - np.array([pose.x_m, pose.y_m])
    z = rel @ fwd
    xc = rel @ right
    yc = pose.height_m - points_enu[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        px = np.column_stack([canvas.cx + canvas.focal_px * xc / z, canvas.cy + canvas.focal_px * yc / z])
    return px, z


_CAR_BOXES = (  # (centre offset along, length, width, z0, z1) metres: body, cabin
    (0.0, 4.4, 1.8, 0.28, 1.0),
    (-0.25, 2.5, 1.6, 1.0, 1.45),
)
_CABIN_TOP_INSET_M = 0.45  # the cabin's top is shorter at each end: slanted windscreen and rear window
_WHEEL_ANGLES = np.linspace(0, 2 * np.pi, 12, endpoint=False)


def _car_geometry(c: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, list[tuple[str, np.ndarray]]]:
    """All polygons of a parked car at ``c`` along ``d``: (P, 3) points and [(kind, point indices)].

    Kinds: ``shadow``, ``{front,back,side,top}{0,1}`` box faces (0 body, 1 cabin), ``wheel``, ``lamp_f``, ``lamp_b``.
    Box faces come with their outward normal as the last 'point' (not drawn).
    """
    n = np.array([d[1], -d[0]])
    pts: list[np.ndarray] = []
    polys: list[tuple[str, np.ndarray]] = []

    def add(kind: str, p: np.ndarray) -> None:
        start = sum(len(q) for q in pts)
        pts.append(p)
        polys.append((kind, np.arange(start, start + len(p))))

    fp = np.array([c + d * 2.5 + n * 1.1, c + d * 2.5 - n * 1.1, c - d * 2.5 - n * 1.1, c - d * 2.5 + n * 1.1])
    add("shadow", np.column_stack([fp, np.zeros(4)]))
    for box_i, (off, length, width, z0, z1) in enumerate(_CAR_BOXES):
        centre = c + d * off
        hl, hw = length / 2, width / 2
        c2 = np.array(
            [centre + d * hl + n * hw, centre + d * hl - n * hw, centre - d * hl - n * hw, centre - d * hl + n * hw]
        )
        lo = np.column_stack([c2, np.full(4, z0)])
        inset = _CABIN_TOP_INSET_M if box_i == 1 else 0.0
        c2t = c2 - np.outer([1.0, 1.0, -1.0, -1.0], d) * inset
        hi = np.column_stack([c2t, np.full(4, z1)])
        slope = inset / (z1 - z0)
        for (i, j), normal, kind in (
            ((0, 1), d, "front"),
            ((1, 2), -n, "side"),
            ((2, 3), -d, "back"),
            ((3, 0), n, "side"),
        ):
            n3 = np.array([*normal, slope if kind != "side" else 0.0])
            add(f"{kind}{box_i}", np.array([lo[i], lo[j], hi[j], hi[i], n3 / np.linalg.norm(n3)]))
        add(f"top{box_i}", np.vstack([hi, [0.0, 0.0, 1.0]]))
    for side in (-1.0, 1.0):
        for sgn in (-1.0, 1.0):
            wc = c + d * 1.35 * sgn + n * side * 0.92
            add(
                "wheel",
                np.column_stack(
                    [
                        wc[0] + d[0] * 0.33 * np.cos(_WHEEL_ANGLES),
                        wc[1] + d[1] * 0.33 * np.cos(_WHEEL_ANGLES),
                        0.33 + 0.33 * np.sin(_WHEEL_ANGLES),
                    ]
                ),
            )
    for end, kind in ((1.0, "lamp_f"), (-1.0, "lamp_b")):
        face = c + d * (2.2 * end + 0.01 * end)
        for sgn in (-1.0, 1.0):
            m = face + n * sgn * 0.7
            add(
                kind,
                np.array(
                    [[*(m + n * 0.15), 0.72], [*(m - n * 0.15), 0.72], [*(m - n * 0.15), 0.85], [*(m + n * 0.15), 0.85]]
                ),
            )
    return np.concatenate(pts), polys


_CAR_FACE_KINDS = ("front", "back", "side", "top")  # a face kind is one of these + "0" (body) or "1" (cabin)


def _fill_car_polygon(img: np.ndarray, local_px: np.ndarray, idx: np.ndarray, colour: tuple[float, ...] | int) -> None:
    """Fill one convex polygon of a car (point indices ``idx`` into ``local_px``, patch pixels) into ``img``."""
    cv2.fillConvexPoly(img, np.round(local_px[idx] * 16).astype(np.int32), colour, cv2.LINE_8, 4)


def _visible_car_faces(
    polys: list[tuple[str, np.ndarray]], pts: np.ndarray, cam: np.ndarray, d: np.ndarray
) -> tuple[list[tuple[float, str, np.ndarray, np.ndarray]], set[int]]:
    """The car's box faces that face the camera and which long sides of the body are seen.

    Returns [(distance to the camera m, kind, corner indices, outward normal)] and the set of visible
    body sides (+1: the side along +n, the left normal of direction ``d``; -1 the other).
    """
    faces = []
    visible_sides = set()
    for kind, idx in polys:
        if kind[:-1] in _CAR_FACE_KINDS:
            quad, normal = pts[idx[:-1]], pts[idx[-1]]
            centre = quad.mean(axis=0)
            if np.dot(cam - centre, normal) > 0:
                faces.append((float(np.linalg.norm(cam - centre)), kind, idx[:-1], normal))
                if kind == "side0":
                    visible_sides.add(round(float(np.dot(normal[:2], [d[1], -d[0]]))))  # +1: the +n side
    return faces, visible_sides


def _draw_car_details(
    polys: list[tuple[str, np.ndarray]],
    faces: list[tuple[float, str, np.ndarray, np.ndarray]],
    visible_sides: set[int],
    local_px: np.ndarray,
    patch: np.ndarray,
    mask: np.ndarray,
) -> None:
    """Wheels on the visible sides and lamps on the visible front/back, into the car's patch and mask."""
    wheel_i = 0
    for kind, idx in polys:
        if kind == "wheel":
            side = -1 if wheel_i < 2 else 1  # the first two wheels are on the -n side
            wheel_i += 1
            if side in visible_sides:
                _fill_car_polygon(patch, local_px, idx, (0.04, 0.04, 0.04))
                _fill_car_polygon(mask, local_px, idx, 1)
        elif kind in ("lamp_f", "lamp_b"):
            face = "front0" if kind == "lamp_f" else "back0"
            if any(f[1] == face for f in faces):
                _fill_car_polygon(patch, local_px, idx, (0.92, 0.92, 0.86) if kind == "lamp_f" else (0.75, 0.08, 0.06))


def _draw_car(
    k: int,
    scene: Scene,
    pose: Pose,
    canvas: Intrinsics,
    rgb: np.ndarray,
    lab: np.ndarray,
    bld: np.ndarray,
    fcd: np.ndarray,
    zbuf: np.ndarray,
    light: tuple[float, float],
) -> None:
    """Draw car ``k`` (its shadow, faces, wheels, lamps) into the canvas layers where it is nearest."""
    cars = scene.cars
    c, d, body = cars.xy[k], cars.direction[k], cars.rgb[k]
    cam = np.array([pose.x_m, pose.y_m, pose.height_m])
    pts, polys = _car_geometry(c, d)
    px, z = _project(pts, pose, canvas)
    is_normal = np.zeros(len(pts), bool)
    for kind, idx in polys:
        if kind[:-1] in _CAR_FACE_KINDS:
            is_normal[idx[-1]] = True
    if np.any(z[~is_normal] < 0.5):
        return
    real = px[~is_normal]
    x0 = max(0, int(np.floor(real[:, 0].min())))
    x1 = min(canvas.width, int(np.ceil(real[:, 0].max())) + 1)
    y0 = max(0, int(np.floor(real[:, 1].min())))
    y1 = min(canvas.height, int(np.ceil(real[:, 1].max())) + 1)
    if x1 <= x0 or y1 <= y0:
        return
    depth = float(z[~is_normal].min())
    detailed = (y1 - y0) > 14
    patch = np.zeros((y1 - y0, x1 - x0, 3), np.float32)
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    ambient, direct = light
    sun = scene.sun.vector
    glass = np.array([0.07, 0.08, 0.10])
    local_px = px - np.array([x0, y0])

    for kind, idx in polys:
        if kind == "shadow":
            shadow = np.zeros_like(mask)
            _fill_car_polygon(shadow, local_px, idx, 1)
            sel = (shadow > 0) & (lab[y0:y1, x0:x1] == labels.ROAD)
            rgb[y0:y1, x0:x1][sel] *= 0.45
    faces, visible_sides = _visible_car_faces(polys, pts, cam, d)
    for _, kind, idx, normal in sorted(faces, key=lambda item: -item[0]):
        lam = max(0.0, float(normal @ sun))
        colour = body * (ambient + direct * lam)
        if kind in ("side1", "front1", "back1"):
            colour = glass + 0.1 * (ambient + direct * lam)
        _fill_car_polygon(patch, local_px, idx, tuple(float(x) for x in colour))
        _fill_car_polygon(mask, local_px, idx, 1)
    if detailed:
        _draw_car_details(polys, faces, visible_sides, local_px, patch, mask)
    sel = (mask > 0) & (zbuf[y0:y1, x0:x1] > depth)
    rgb[y0:y1, x0:x1][sel] = patch[sel]
    lab[y0:y1, x0:x1][sel] = labels.CAR
    bld[y0:y1, x0:x1][sel] = -1
    fcd[y0:y1, x0:x1][sel] = -1
    zbuf[y0:y1, x0:x1][sel] = depth


def _draw_tree(
    k: int,
    scene: Scene,
    pose: Pose,
    canvas: Intrinsics,
    rgb: np.ndarray,
    lab: np.ndarray,
    bld: np.ndarray,
    fcd: np.ndarray,
    zbuf: np.ndarray,
    light: tuple[float, float],
) -> None:
    trees = scene.trees
    px, z = _project(np.array([[*trees.xy[k], 0.0]]), pose, canvas)
    depth = float(z[0])
    f = canvas.focal_px
    width_px = f * trees.crown_m[k] / depth
    height_px = f * trees.height_m[k] / depth
    left = px[0, 0] - width_px / 2
    bottom = px[0, 1]
    top = bottom - height_px
    x0, x1 = max(0, int(np.floor(left))), min(canvas.width, int(np.ceil(left + width_px)))
    y0, y1 = max(0, int(np.floor(top))), min(canvas.height, int(np.ceil(bottom)))
    if x1 <= x0 or y1 <= y0:
        return
    sprite = scene.tree_sprites[trees.sprite[k]]
    sh, sw = sprite.shape[:2]
    sx, sy = width_px / sw, height_px / sh
    m = np.array([[sx, 0.0, left - x0 + 0.5 * sx - 0.5], [0.0, sy, top - y0 + 0.5 * sy - 0.5]])
    warped = cv2.warpAffine(sprite, m, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    alpha = warped[..., 3]
    ok = (alpha > 0.02) & (zbuf[y0:y1, x0:x1] > depth)
    if not ok.any():
        return
    ambient, direct = light
    tint = 0.85 + 0.3 * ((_hash(np.int64(scene.seed), np.int64(k)) % np.uint64(100)) / 100.0)
    colour = warped[..., :3] * float(tint) * (ambient + 0.6 * direct)
    a = (alpha * ok)[..., None]
    region = rgb[y0:y1, x0:x1]
    region[:] = region * (1 - a) + colour * a
    solid = ok & (alpha > 0.5)
    lab[y0:y1, x0:x1][solid] = labels.TREE
    bld[y0:y1, x0:x1][solid] = -1
    fcd[y0:y1, x0:x1][solid] = -1
    zbuf[y0:y1, x0:x1][solid] = depth


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
    canvas = _upright_canvas(pose, intrinsics)
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
    colour = _shade_buildings(scene, bid, fid, u_m, v_m, footprint)
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
        _draw_occluders(scene, pose, canvas, rgb, lab, bld, fcd, zbuf, light)

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


def _draw_occluders(
    scene: Scene,
    pose: Pose,
    canvas: Intrinsics,
    rgb: np.ndarray,
    lab: np.ndarray,
    bld: np.ndarray,
    fcd: np.ndarray,
    zbuf: np.ndarray,
    light: tuple[float, float],
) -> None:
    pos = np.array([pose.x_m, pose.y_m])
    yaw = math.radians(pose.yaw_deg)
    fwd = np.array([math.sin(yaw), math.cos(yaw)])
    right = np.array([math.cos(yaw), -math.sin(yaw)])
    half = math.atan((canvas.width - canvas.cx) / canvas.focal_px), math.atan(canvas.cx / canvas.focal_px)
    tan_half = math.tan(max(half))
    items: list[tuple[float, str, int]] = []
    for kind, xy, radius in (("tree", scene.trees.xy, 4.0), ("car", scene.cars.xy, 2.5)):
        if len(xy) == 0:
            continue
        rel = xy - pos
        z = rel @ fwd
        x = rel @ right
        ok = (z > OCCLUDER_RANGE_M[0]) & (z < OCCLUDER_RANGE_M[1]) & (np.abs(x) < z * tan_half + radius)
        items.extend((float(z[i]), kind, int(i)) for i in np.flatnonzero(ok))
    for _, kind, i in sorted(items, reverse=True):
        if kind == "tree":
            _draw_tree(i, scene, pose, canvas, rgb, lab, bld, fcd, zbuf, light)
        else:
            _draw_car(i, scene, pose, canvas, rgb, lab, bld, fcd, zbuf, light)


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
