"""Vanishing points: the vertical one and several horizontal ones, from line segments.

Method (no single Manhattan frame is assumed, as in the paper):

1. **Vertical VP.** Candidate directions on the Gaussian sphere are the intersections (cross
   products of interpretation-plane normals) of pairs of near-vertical segments, plus the level
   camera's vertical (0, 1, 0). Each candidate is scored by the length-weighted consistency of
   all near-vertical segments; the best one is refined by least squares on its inliers.
2. **Horizontal VPs.** A horizontal direction is perpendicular to the vertical, so it has a single
   degree of freedom: its angle in the horizon plane, which *is* the facade orientation theta of
   :mod:`geoloc.core.camera` (``d = cos(theta) x' - sin(theta) z'`` in the upright frame). Every
   theta on a fine grid (0.2 deg) is scored against every remaining segment (an exhaustive
   consensus search, stronger than sampling); VPs are then picked greedily, each pick only
   counting the evidence not already explained by earlier picks. Segments lying along the
   horizon line (consistent with nearly every theta, hence uninformative) are down-weighted.
3. **Re-assignment and joint refinement.** Segments are re-assigned to the most consistent VP
   (or -1); then pitch, roll and all horizontal thetas are refined together by weighted least
   squares (``sum L^2 (n_i . d)^2`` over inliers, ``n_i`` the segment's interpretation-plane normal,
   plus a Gaussian prior towards a level camera), so the vertical and the horizontal VPs stay
   exactly orthogonal; VPs that converge together are merged, weak ones dropped. Iterated a few
   times.

Consistency of a segment with a VP: let ``u`` be the image line from the segment's midpoint to
the VP (works for VPs at infinity) and ``err`` the angle between the segment and ``u``. The
residual is ``max(d / tol_px, err / max_angle_deg)`` with ``d = L/2 sin(err)`` the distance of
the segment's endpoints from ``u`` (long segments are held to a tight angle, short ones to
``max_angle_deg``); inliers have residual <= 1.

Frames: camera frame x right, y down, z forward. The *upright* frame has the same heading but
no pitch or roll: y' = world down, z' = the optical axis projected on the horizontal plane,
x' = y' x z'. ``theta_deg`` of each horizontal VP is :func:`geoloc.core.camera.orientation_from_direction`
of its upright-frame direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from geoloc.core.camera import Intrinsics, orientation_from_direction, wrap_orientation_deg
from geoloc.vision.vp_geometry import (
    SegmentGeometry,
    horizontal_direction_cam,
    inlier_weight,
    pitch_roll_deg,
    rotation_upright_from_pitch_roll,
    segment_geometry,
    smallest_eigenvector,
    upright_rotation,
    vp_residuals,
)


@dataclass
class VanishingPoints:
    """Vanishing points of one image.

    directions_cam: (1 + M, 3) unit directions in the camera frame; row 0 is the vertical
        (world down, y > 0), rows 1..M horizontal VPs, strongest first.
    theta_deg: (1 + M,) facade orientation of each horizontal VP (deg, [-90, 90)); NaN for row 0.
    assignment: (N,) per input segment the row it belongs to, -1 for outliers.
    support_px: (1 + M,) summed length (px) of the segments assigned to each VP.
    pitch_deg: optical axis above the horizon (deg, + = looking up).
    roll_deg: camera roll (deg, + = image right side below the horizon, i.e. the camera turned
        clockwise as seen from behind).
    vertical_found: whether the vertical came from image evidence (else a level camera is assumed,
        up to what the horizontal VPs say).
    rotation_upright_from_cam: (3, 3) maps camera-frame vectors to the upright frame (rows x', y', z').
    """

    directions_cam: np.ndarray
    theta_deg: np.ndarray
    assignment: np.ndarray
    support_px: np.ndarray
    pitch_deg: float
    roll_deg: float
    vertical_found: bool
    rotation_upright_from_cam: np.ndarray

    @property
    def n_horizontal(self) -> int:
        """Number of horizontal vanishing points."""
        return len(self.directions_cam) - 1

    @property
    def directions_upright(self) -> np.ndarray:
        """(1 + M, 3) the VP directions in the upright camera frame."""
        directions: np.ndarray = self.directions_cam @ self.rotation_upright_from_cam.T
        return directions

    def image_points(self, intrinsics: Intrinsics) -> np.ndarray:
        """(1 + M, 2) VP positions in pixels (+-inf / large where a VP is at or near infinity)."""
        v = self.directions_cam @ intrinsics.matrix.T
        with np.errstate(divide="ignore", invalid="ignore"):
            xy: np.ndarray = v[:, :2] / v[:, 2:3]
        far = np.abs(v[:, 2]) < 1e-9
        xy[far] = np.copysign(np.inf, v[far, :2] + 0.0)
        return xy

    def horizon_line(self, intrinsics: Intrinsics) -> np.ndarray:
        """Homogeneous image line (a, b, c) of the horizon: a x + b y + c = 0 (pixels)."""
        g = self.directions_cam[0]
        line = np.linalg.inv(intrinsics.matrix).T @ g
        normalised: np.ndarray = line / np.hypot(line[0], line[1])
        return normalised

    def to_dict(self, intrinsics: Intrinsics | None = None) -> dict[str, Any]:
        """JSON-friendly summary."""
        out: dict[str, Any] = {
            "pitch_deg": round(float(self.pitch_deg), 3),
            "roll_deg": round(float(self.roll_deg), 3),
            "vertical_found": bool(self.vertical_found),
            "vertical": {
                "direction_cam": [round(float(v), 6) for v in self.directions_cam[0]],
                "n_segments": int(np.sum(self.assignment == 0)),
                "support_px": round(float(self.support_px[0]), 1),
            },
            "horizontal": [],
        }
        pts = self.image_points(intrinsics) if intrinsics is not None else None
        for k in range(1, len(self.directions_cam)):
            entry = {
                "index": k,
                "theta_deg": round(float(self.theta_deg[k]), 3),
                "direction_cam": [round(float(v), 6) for v in self.directions_cam[k]],
                "n_segments": int(np.sum(self.assignment == k)),
                "support_px": round(float(self.support_px[k]), 1),
            }
            if pts is not None:
                entry["image_xy"] = [float(v) if np.isfinite(v) and abs(v) < 1e9 else None for v in pts[k]]
            out["horizontal"].append(entry)
        return out


def _refine_jointly(
    normals_cam: np.ndarray,
    assignment: np.ndarray,
    weights: np.ndarray,
    pitch_deg: float,
    roll_deg: float,
    theta_deg: np.ndarray,
    prior_weight: float,
) -> tuple[float, float, np.ndarray]:
    """Weighted least squares over (pitch, roll, theta_1..M) of sum w_i (n_i . d_{a(i)})^2.

    The vertical and all horizontal VPs share one upright frame, so they stay exactly orthogonal;
    a weak prior (``prior_weight``, in the units of ``weights``) keeps pitch and roll near zero when
    the image says little about them.
    """
    used = (assignment >= 0) & (weights > 0)
    if used.sum() < 3:
        return pitch_deg, roll_deg, theta_deg
    n_used = normals_cam[used]
    a_used = assignment[used]
    sw = np.sqrt(weights[used])
    sp = math.sqrt(prior_weight)

    def residuals(params: np.ndarray) -> np.ndarray:
        rot = rotation_upright_from_pitch_roll(math.degrees(params[0]), math.degrees(params[1]))
        t = params[2:]
        dirs = np.vstack([rot[1], np.cos(t)[:, None] * rot[0] - np.sin(t)[:, None] * rot[2]])
        dots = np.einsum("ij,ij->i", n_used, dirs[a_used])
        return np.concatenate([sw * dots, [sp * params[0], sp * params[1]]])

    # Levenberg-Marquardt with a forward-difference Jacobian (2 + M parameters, a few iterations).
    x = np.radians(np.concatenate([[pitch_deg, roll_deg], np.asarray(theta_deg, dtype=float)]))
    r = residuals(x)
    cost = float(r @ r)
    damping = 1e-3
    eps = 1e-6
    for _ in range(30):
        jac = np.empty((len(r), len(x)))
        for j in range(len(x)):
            step = np.zeros_like(x)
            step[j] = eps
            jac[:, j] = (residuals(x + step) - r) / eps
        jtj, jtr = jac.T @ jac, jac.T @ r
        accepted = False
        while damping < 1e8:
            delta = -np.linalg.solve(jtj + damping * np.diag(np.diag(jtj) + 1e-12), jtr)
            r_new = residuals(x + delta)
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                accepted = True
                break
            damping *= 10.0
        if not accepted:
            break
        decrease = cost - cost_new
        x, r, cost, damping = x + delta, r_new, cost_new, max(damping / 10.0, 1e-9)
        if decrease < 1e-12 * max(cost, 1e-30) or float(np.max(np.abs(delta))) < 1e-10:
            break
    out = np.degrees(x)
    return float(out[0]), float(out[1]), wrap_orientation_deg(out[2:])


# ----------------------------------------------------------------------------------------------
# Estimation


def _estimate_vertical(
    geo: SegmentGeometry,
    intrinsics: Intrinsics,
    tol_px: float,
    max_angle_deg: float,
    max_tilt_deg: float,
    min_inliers: int,
    rng: np.random.Generator,
    n_pair_samples: int,
) -> tuple[np.ndarray, bool]:
    """World-down direction in the camera frame (unit, y > 0) and whether image evidence supports it."""
    prior = np.array([0.0, 1.0, 0.0])
    cand_idx = np.flatnonzero(geo.tilt_from_vertical_deg <= max_tilt_deg)
    if len(cand_idx) < 2:
        return prior, False
    normals = geo.normals_cam[cand_idx]
    lengths = geo.lengths_px[cand_idx]
    # Pairs: all pairs of the longest 40 plus length-weighted random pairs.
    top = np.argsort(-lengths)[:40]
    ii, jj = np.triu_indices(len(top), k=1)
    pairs = [np.stack([top[ii], top[jj]], axis=1)]
    if n_pair_samples > 0:
        p = lengths / lengths.sum()
        pairs.append(rng.choice(len(cand_idx), size=(n_pair_samples, 2), p=p))
    pairs_arr = np.concatenate(pairs)
    cands = np.cross(normals[pairs_arr[:, 0]], normals[pairs_arr[:, 1]])
    norms = np.linalg.norm(cands, axis=1)
    cands = cands[norms > 1e-9] / norms[norms > 1e-9, None]
    cands *= np.sign(cands[:, 1:2] + 1e-12)
    cands = np.vstack([prior, cands])
    cos_tilt = cands[:, 1]
    cands = cands[cos_tilt >= math.cos(math.radians(max_tilt_deg))]
    sub = SegmentGeometry(
        geo.midpoints[cand_idx], geo.unit_dirs[cand_idx], lengths, normals, geo.tilt_from_vertical_deg[cand_idx]
    )
    # Chunk to bound memory.
    best_score, best = -1.0, prior
    for start in range(0, len(cands), 512):
        chunk = cands[start : start + 512]
        score = inlier_weight(vp_residuals(chunk, sub, intrinsics, tol_px, max_angle_deg)) @ lengths
        j = int(np.argmax(score))
        if score[j] > best_score:
            best_score, best = float(score[j]), chunk[j]
    g = best
    for _ in range(3):
        res = vp_residuals(g, sub, intrinsics, tol_px, max_angle_deg)[0]
        inl = res <= 1.0
        if inl.sum() < 2:
            break
        w = lengths[inl] * inlier_weight(res[inl])
        a = (normals[inl] * w[:, None]).T @ normals[inl]
        g = smallest_eigenvector(a)
        g *= np.sign(g[1] + 1e-12)
    res = vp_residuals(g, sub, intrinsics, tol_px, max_angle_deg)[0]
    found = int(np.sum(res <= 1.0)) >= min_inliers
    return (g if found else prior), found


@dataclass(frozen=True)
class VanishingOptions:
    """How :func:`estimate_vanishing_points` searches: tolerances, limits, the prior and the seed."""

    tol_px: float | None = None
    """Endpoint distance tolerance (px); None: ``max(1.5, 0.002 * image diagonal)``."""
    max_angle_deg: float = 2.5
    """Angular tolerance for short segments (deg)."""
    max_tilt_deg: float = 30.0
    """The vertical VP is searched within this angle of the camera's y axis (bounds |pitch| and |roll|), and
    only segments within it of the image vertical vote for it (deg)."""
    max_horizontal: int = 6
    """At most this many horizontal VPs."""
    min_inliers: int = 5
    """A horizontal VP needs at least this many segments..."""
    min_support_frac: float = 0.05
    """...and this share of the (informativeness-weighted) horizontal evidence."""
    min_separation_deg: float = 5.0
    """Two horizontal VPs closer than this in theta are merged (deg)."""
    theta_step_deg: float = 0.2
    """Grid step of the exhaustive horizontal search (deg)."""
    n_iterations: int = 3
    """Rounds of re-assignment + joint refinement."""
    pitch_roll_prior_deg: float = 3.0
    """Gaussian prior (std, deg) on pitch and roll around a level camera, relative to ``line_noise_px``. On the
    28 Lund photos with usable accelerometer data, 3 deg / 3 px gave the smallest spread of pitch errors."""
    line_noise_px: float = 3.0
    """The assumed endpoint noise of the segments (px)."""
    seed: int = 0
    """For the random segment pairs of the vertical search."""


def estimate_vanishing_points(
    segments: np.ndarray, intrinsics: Intrinsics, options: VanishingOptions | None = None
) -> VanishingPoints:
    """Estimate the vertical and several horizontal vanishing points from line segments.

    segments: (N, 4) ``x1, y1, x2, y2`` in pixels of the image described by ``intrinsics``.
    options: the search's tolerances and limits (default :class:`VanishingOptions`).
    Returns :class:`VanishingPoints` (see there for frames and units).
    """
    o = options or VanishingOptions()
    tol_px, max_angle_deg, max_tilt_deg, max_horizontal = o.tol_px, o.max_angle_deg, o.max_tilt_deg, o.max_horizontal
    min_inliers, min_support_frac, min_separation_deg = o.min_inliers, o.min_support_frac, o.min_separation_deg
    theta_step_deg, n_iterations, seed = o.theta_step_deg, o.n_iterations, o.seed
    pitch_roll_prior_deg, line_noise_px = o.pitch_roll_prior_deg, o.line_noise_px
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    n = len(seg)
    diag = float(np.hypot(intrinsics.width, intrinsics.height))
    tol = tol_px if tol_px is not None else max(1.5, 0.002 * diag)
    rng = np.random.default_rng(seed)
    geo = segment_geometry(seg, intrinsics)
    if n == 0:
        rot = upright_rotation(np.array([0.0, 1.0, 0.0]))
        return VanishingPoints(
            np.array([[0.0, 1.0, 0.0]]), np.array([np.nan]), np.zeros(0, int), np.zeros(1), 0.0, 0.0, False, rot
        )

    g, vertical_found = _estimate_vertical(geo, intrinsics, tol, max_angle_deg, max_tilt_deg, 2, rng, 2000)
    thetas = np.arange(-90.0, 90.0, theta_step_deg)

    def horizontal_search(g_cam: np.ndarray) -> np.ndarray:
        """Greedy horizontal VP picks (thetas) given the vertical."""
        rot = upright_rotation(g_cam)
        res_v = vp_residuals(g_cam, geo, intrinsics, tol, max_angle_deg)[0]
        rest = np.flatnonzero(res_v > 1.0)
        if len(rest) < min_inliers:
            return np.zeros(0)
        sub = SegmentGeometry(
            geo.midpoints[rest],
            geo.unit_dirs[rest],
            geo.lengths_px[rest],
            geo.normals_cam[rest],
            geo.tilt_from_vertical_deg[rest],
        )
        dirs = horizontal_direction_cam(thetas, rot)
        res_h = vp_residuals(dirs, sub, intrinsics, tol, max_angle_deg)  # (T, N)
        kern = inlier_weight(res_h)
        # A picked VP also explains its near-inliers (residual < 2), so that their tails do not
        # seed spurious VPs next to it.
        kern_wide = inlier_weight(res_h / 2.0)
        consistent_share = np.mean(kern > 0.0, axis=0)
        informative = np.minimum(1.0, 0.05 / np.maximum(consistent_share, 1e-9))
        w = sub.lengths_px * informative
        total = float(w.sum())
        explained = np.zeros(len(rest))
        picks: list[float] = []
        for _ in range(max_horizontal):
            score = np.clip(kern - explained[None, :], 0.0, None) @ w
            for t in picks:
                near = np.abs(wrap_orientation_deg(thetas - t)) < min_separation_deg
                score[near] = -1.0
            j = int(np.argmax(score))
            n_in = int(np.sum(kern[j] > 0.0))
            if score[j] < min_support_frac * total or n_in < min_inliers:
                break
            picks.append(float(thetas[j]))
            explained = np.maximum(explained, kern_wide[j])
        return np.array(picks)

    theta_h = horizontal_search(g)
    pitch, roll = pitch_roll_deg(g)
    for _ in range(n_iterations):
        rot = rotation_upright_from_pitch_roll(pitch, roll)
        dirs = np.vstack([rot[1], horizontal_direction_cam(theta_h, rot)])
        res = vp_residuals(dirs, geo, intrinsics, tol, max_angle_deg)
        assignment = np.where(res.min(axis=0) <= 1.0, np.argmin(res, axis=0), -1)
        counts = np.bincount(assignment[assignment >= 0], minlength=len(dirs))
        keep = np.flatnonzero(counts[1:] >= min_inliers)
        theta_h = theta_h[keep]
        remap = np.full(len(dirs), -1)
        remap[0] = 0
        remap[keep + 1] = np.arange(1, len(keep) + 1)
        assignment = np.where(assignment >= 0, remap[np.maximum(assignment, 0)], -1)
        vertical_found = bool(np.sum(assignment == 0) >= min_inliers)
        # Weights ~ L^2 (the direction of a segment is known to ~ noise / L), times the soft inlier kernel.
        weights = np.where(assignment >= 0, geo.lengths_px**2, 0.0)
        weights[assignment >= 0] *= inlier_weight(res[np.maximum(assignment, 0), np.arange(n)][assignment >= 0])
        # Residual n.d of a segment has a standard deviation of about line_noise_px / L, so with
        # weights L^2 the data term is in units of line_noise_px^2 and a Gaussian prior of
        # pitch_roll_prior_deg on pitch and roll weighs (line_noise_px / sigma_rad)^2.
        prior_weight = (line_noise_px / math.radians(pitch_roll_prior_deg)) ** 2
        pitch, roll, theta_h = _refine_jointly(geo.normals_cam, assignment, weights, pitch, roll, theta_h, prior_weight)
        # Merge VPs that converged together (keep the stronger).
        support_h = np.array([weights[assignment == k + 1].sum() for k in range(len(theta_h))])
        merged: list[float] = []
        for k in np.argsort(-support_h):
            t = float(theta_h[k])
            if all(abs(float(wrap_orientation_deg(t - m))) >= min_separation_deg for m in merged):
                merged.append(t)
        theta_h = np.array(merged)

    # Final assignment and ordering by support.
    rot = rotation_upright_from_pitch_roll(pitch, roll)
    dirs = np.vstack([rot[1], horizontal_direction_cam(theta_h, rot)])
    res = vp_residuals(dirs, geo, intrinsics, tol, max_angle_deg)
    assignment = np.where(res.min(axis=0) <= 1.0, np.argmin(res, axis=0), -1)
    support = np.bincount(assignment[assignment >= 0], weights=geo.lengths_px[assignment >= 0], minlength=len(dirs))
    keep_h = [k for k in range(1, len(dirs)) if np.sum(assignment == k) >= min_inliers]
    keep_h.sort(key=lambda k: -support[k])
    rows = [0, *keep_h]
    remap = np.full(len(dirs), -1)
    remap[rows] = np.arange(len(rows))
    assignment = np.where(assignment >= 0, remap[np.maximum(assignment, 0)], -1)
    dirs = dirs[rows]
    theta = np.concatenate([[np.nan], orientation_from_direction(dirs[1:] @ rot.T)])
    vertical_found = bool(np.sum(assignment == 0) >= min_inliers)
    return VanishingPoints(
        directions_cam=dirs,
        theta_deg=theta,
        assignment=assignment,
        support_px=support[rows],
        pitch_deg=pitch,
        roll_deg=roll,
        vertical_found=bool(vertical_found),
        rotation_upright_from_cam=rot,
    )
