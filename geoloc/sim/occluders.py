"""Occluders of the simulated photos: street trees (billboards) and parked cars (two boxes with wheels).

They are drawn far to near on the upright canvas (:func:`geoloc.sim.pose.upright_canvas`) after the
buildings, the ground and the sky, with a depth test against those layers' depth buffer; a pixel they
cover shows no building or facade any more (ids -1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from geoloc.core import labels
from geoloc.core.camera import Intrinsics
from geoloc.sim.pose import Pose
from geoloc.sim.scene import Scene
from geoloc.sim.shading import hash_ints

OCCLUDER_RANGE_M = (2.5, 150.0)  # trees and cars nearer or farther than this are not drawn


@dataclass
class CanvasLayers:
    """The upright canvas being drawn (Hc x Wc), all written in place.

    rgb: (Hc, Wc, 3) float32 linear RGB in [0, 1]; labels: (Hc, Wc) uint8 class codes
    (:mod:`geoloc.core.labels`); building_id, facade_id: (Hc, Wc) int32, -1 where none;
    depth_m: (Hc, Wc) float32 optical depth (metres), inf where sky.
    """

    rgb: np.ndarray
    labels: np.ndarray
    building_id: np.ndarray
    facade_id: np.ndarray
    depth_m: np.ndarray

    def cover(self, window: tuple[slice, slice], sel: np.ndarray, label: int, depth_m: float) -> None:
        """Mark the ``sel`` pixels of ``window`` as an occluder ``label`` at ``depth_m``, hiding any facade."""
        self.labels[window][sel] = label
        self.building_id[window][sel] = -1
        self.facade_id[window][sel] = -1
        self.depth_m[window][sel] = depth_m


def draw_occluders(
    scene: Scene,
    pose: Pose,
    canvas: Intrinsics,
    layers: CanvasLayers,
    light: tuple[float, float],
) -> None:
    """Draw the trees and parked cars in view (within ``OCCLUDER_RANGE_M``) far to near into ``layers``.

    canvas: the upright canvas's intrinsics; light: (ambient, direct) sun light factors.
    """
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
            _draw_tree(i, scene, pose, canvas, layers, light)
        else:
            _draw_car(i, scene, pose, canvas, layers, light)


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
    layers: CanvasLayers,
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

    window = np.s_[y0:y1, x0:x1]
    for kind, idx in polys:
        if kind == "shadow":
            shadow = np.zeros_like(mask)
            _fill_car_polygon(shadow, local_px, idx, 1)
            sel = (shadow > 0) & (layers.labels[window] == labels.ROAD)
            layers.rgb[window][sel] *= 0.45
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
    sel = (mask > 0) & (layers.depth_m[window] > depth)
    layers.rgb[window][sel] = patch[sel]
    layers.cover(window, sel, labels.CAR, depth)


def _draw_tree(
    k: int,
    scene: Scene,
    pose: Pose,
    canvas: Intrinsics,
    layers: CanvasLayers,
    light: tuple[float, float],
) -> None:
    """Draw tree ``k`` (a billboard sprite, alpha-blended) into the canvas layers where it is nearest."""
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
    window = np.s_[y0:y1, x0:x1]
    ok = (alpha > 0.02) & (layers.depth_m[window] > depth)
    if not ok.any():
        return
    ambient, direct = light
    tint = 0.85 + 0.3 * ((hash_ints(np.int64(scene.seed), np.int64(k)) % np.uint64(100)) / 100.0)
    colour = warped[..., :3] * float(tint) * (ambient + 0.6 * direct)
    a = (alpha * ok)[..., None]
    region = layers.rgb[window]
    region[:] = region * (1 - a) + colour * a
    layers.cover(window, ok & (alpha > 0.5), labels.TREE, depth)
