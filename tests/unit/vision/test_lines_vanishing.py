"""Line segments and vanishing points: synthetic line sets with known answers, real photos."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geoloc.core.camera import Intrinsics, vanishing_column_of_orientation, wrap_orientation_deg
from geoloc.vision.lines import detect_line_segments
from geoloc.vision.vanishing import estimate_vanishing_points
from geoloc.vision.vp_geometry import (
    SegmentGeometry,
    pitch_roll_deg,
    rotation_upright_from_pitch_roll,
    segment_geometry,
    vp_residuals,
)

INTR = Intrinsics.from_hfov(1024, 768, 62.0)


def render_segments(
    intr: Intrinsics,
    pitch_deg: float,
    roll_deg: float,
    thetas_deg: list[float],
    n_per_direction: int = 40,
    noise_px: float = 0.5,
    n_outliers: int = 30,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Segments of 3D lines along the vertical and horizontal directions ``thetas_deg`` (upright frame).

    Seen by a camera with the given pitch and roll, with endpoint noise and random outlier segments.

    Returns (segments (N, 4) px, true label per segment: 0 vertical, k horizontal k, -1 outlier).
    """
    rng = np.random.default_rng(seed)
    cam_from_up = rotation_upright_from_pitch_roll(pitch_deg, roll_deg).T
    dirs = [np.array([0.0, 1.0, 0.0])]
    dirs += [np.array([math.cos(math.radians(t)), 0.0, -math.sin(math.radians(t))]) for t in thetas_deg]
    k_mat = intr.matrix
    segs, labels = [], []
    for label, d in enumerate(dirs):
        count = 0
        while count < n_per_direction:
            p = np.array([rng.uniform(-15, 15), rng.uniform(-8, 1.5), rng.uniform(4, 40)])
            q = p + rng.uniform(0.5, 4.0) * d
            pc, qc = cam_from_up @ p, cam_from_up @ q
            if min(pc[2], qc[2]) < 0.5:
                continue
            a, b = k_mat @ pc, k_mat @ qc
            a, b = a[:2] / a[2], b[:2] / b[2]
            inside = all(0 <= v[0] < intr.width and 0 <= v[1] < intr.height for v in (a, b))
            if not inside or np.hypot(*(b - a)) < 20:
                continue
            segs.append(np.r_[a, b] + rng.normal(0, noise_px, 4))
            labels.append(label)
            count += 1
    for _ in range(n_outliers):
        a = rng.uniform([0, 0], [intr.width, intr.height])
        ang, length = rng.uniform(0, math.pi), rng.uniform(20, 150)
        segs.append(np.r_[a, a + length * np.array([math.cos(ang), math.sin(ang)])])
        labels.append(-1)
    return np.array(segs), np.array(labels)


@pytest.mark.parametrize(
    ("pitch_deg", "roll_deg", "thetas_deg", "seed"),
    [
        (5.0, -3.0, [30.0, -50.0], 0),
        (-4.0, 2.0, [10.0, -75.0, 60.0], 1),
        (8.0, 1.0, [0.0, -40.0], 2),
        (0.0, 0.0, [-88.0, 35.0], 3),
        (2.0, 4.0, [45.0, -45.0, -15.0], 4),
    ],
)
def test_vanishing_points_of_synthetic_lines(
    pitch_deg: float, roll_deg: float, thetas_deg: list[float], seed: int
) -> None:
    segs, truth = render_segments(INTR, pitch_deg, roll_deg, thetas_deg, seed=seed)
    vp = estimate_vanishing_points(segs, INTR)
    assert vp.vertical_found
    assert abs(vp.pitch_deg - pitch_deg) < 0.5
    assert abs(vp.roll_deg - roll_deg) < 0.5
    found = vp.theta_deg[1:]
    for t in thetas_deg:
        errors = np.abs(wrap_orientation_deg(found - t))
        assert errors.min() < 1.0, (t, found)
    # Every true direction is among the strongest VPs; at most one weak spurious extra.
    assert len(thetas_deg) <= vp.n_horizontal <= len(thetas_deg) + 1
    # Assignment: true vertical segments go to row 0, most horizontal ones to their VP.
    assert np.mean(vp.assignment[truth == 0] == 0) > 0.9
    for k, t in enumerate(thetas_deg, start=1):
        row = 1 + int(np.argmin(np.abs(wrap_orientation_deg(found - t))))
        assert np.mean(vp.assignment[truth == k] == row) > 0.8
    # Directions are unit vectors, the horizontal ones orthogonal to the vertical.
    d = vp.directions_cam
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.allclose(d[1:] @ d[0], 0.0, atol=1e-9)


def _residuals_numpy(
    directions_cam: np.ndarray, geo: SegmentGeometry, intrinsics: Intrinsics, tol_px: float, max_angle_deg: float
) -> np.ndarray:
    """The residuals' formula (vp_geometry's docstring) on (M, N, 2) arrays, as before the compiled kernel."""
    v = np.atleast_2d(directions_cam) @ intrinsics.matrix.T
    u = v[:, None, :2] - geo.midpoints[None, :, :] * v[:, None, 2:3]
    norm_u = np.linalg.norm(u, axis=2)
    cross = np.abs(geo.unit_dirs[None, :, 0] * u[..., 1] - geo.unit_dirs[None, :, 1] * u[..., 0])
    sin_err = np.clip(np.divide(cross, norm_u, out=np.zeros_like(cross), where=norm_u > 1e-12), 0.0, 1.0)
    angle_deg = np.degrees(np.arcsin(sin_err))
    residuals: np.ndarray = np.maximum(0.5 * geo.lengths_px[None, :] * sin_err / tol_px, angle_deg / max_angle_deg)
    return residuals


def test_compiled_residuals_match_the_formula() -> None:
    """Finite and infinite VPs, vertical segments and a VP on a segment's midpoint (u = 0: residual 0)."""
    rng = np.random.default_rng(3)
    intrinsics = Intrinsics.from_hfov(640, 480, 60.0)
    segments = rng.uniform(0.0, 640.0, (300, 4))
    segments[:50, 2] = segments[:50, 0]
    geo = segment_geometry(segments, intrinsics)
    directions = rng.normal(size=(400, 3))
    directions[:100, 2] = 0.0
    midpoint_ray = np.linalg.inv(intrinsics.matrix) @ np.array([*geo.midpoints[0], 1.0])
    directions = np.vstack([directions, midpoint_ray])
    compiled = vp_residuals(directions, geo, intrinsics, 1.6, 2.5)
    formula = _residuals_numpy(directions, geo, intrinsics, 1.6, 2.5)
    assert compiled.shape == (401, 300)
    # numpy's arcsin may use SIMD code that differs from libm's in the last bit.
    np.testing.assert_allclose(compiled, formula, rtol=1e-12, atol=1e-12)
    assert compiled[-1, 0] == pytest.approx(0.0, abs=1e-9)
    assert np.all(compiled >= 0.0)


def test_pitch_roll_definitions() -> None:
    # Looking up by 10 deg: world-down has a negative z component in the camera frame.
    down = rotation_upright_from_pitch_roll(10.0, 0.0)[1]
    assert down[2] < 0
    assert pitch_roll_deg(down) == pytest.approx((10.0, 0.0))
    # Right side down by 5 deg: world-down has a positive x component.
    down = rotation_upright_from_pitch_roll(0.0, 5.0)[1]
    assert down[0] > 0
    assert pitch_roll_deg(down) == pytest.approx((0.0, 5.0))


def test_level_camera_vp_column_matches_camera_conventions() -> None:
    segs, _ = render_segments(INTR, 0.0, 0.0, [40.0, -55.0], noise_px=0.2, n_outliers=0, seed=5)
    vp = estimate_vanishing_points(segs, INTR)
    xy = vp.image_points(INTR)
    for k in range(1, vp.n_horizontal + 1):
        expected_x = float(vanishing_column_of_orientation(vp.theta_deg[k], INTR))
        assert xy[k, 0] == pytest.approx(expected_x, rel=1e-6)
        assert xy[k, 1] == pytest.approx(INTR.cy, abs=INTR.height * 0.01)


def test_no_segments_and_only_clutter() -> None:
    vp = estimate_vanishing_points(np.zeros((0, 4)), INTR)
    assert vp.n_horizontal == 0 and not vp.vertical_found
    assert vp.pitch_deg == 0.0 and vp.roll_deg == 0.0
    rng = np.random.default_rng(0)
    clutter = np.hstack([rng.uniform(0, 700, (40, 2)), rng.uniform(0, 700, (40, 2))])
    vp = estimate_vanishing_points(clutter, INTR)
    assert abs(vp.pitch_deg) < 20 and abs(vp.roll_deg) < 20
    assert vp.assignment.shape == (40,)


def test_lsd_on_synthetic_and_odd_sized_images() -> None:
    import cv2

    img = np.zeros((301, 457), np.uint8)
    cv2.line(img, (20, 30), (400, 60), 255, 3)
    cv2.rectangle(img, (100, 120), (300, 280), 180, -1)
    segs = detect_line_segments(img)
    assert segs.ndim == 2 and segs.shape[1] == 4 and len(segs) >= 4
    assert np.all((segs[:, [0, 2]] > -2) & (segs[:, [0, 2]] < 459))
    # RGB input, downscaled detection, results in input pixels.
    big = cv2.resize(np.dstack([img] * 3), (457 * 4, 301 * 4), interpolation=cv2.INTER_NEAREST)
    segs_big = detect_line_segments(big, max_side_px=800)
    assert segs_big.shape[1] == 4 and segs_big[:, [0, 2]].max() > 1200
    assert detect_line_segments(np.zeros((1, 1), np.uint8)).shape == (0, 4)


def test_lsd_on_a_real_photo() -> None:
    from PIL import Image

    from contracts.settings import shared_path

    try:
        folder = shared_path("data", "lund", "images")
    except FileNotFoundError:
        pytest.skip("shared Lund photos not available")
    path = sorted(folder.glob("*.jpg"))[0]
    img = np.asarray(Image.open(path).convert("RGB"))
    segs = detect_line_segments(img)
    assert segs.ndim == 2 and segs.shape[1] == 4
    assert len(segs) > 50
    h, w = img.shape[:2]
    assert np.all(segs[:, [0, 2]] >= -1) and np.all(segs[:, [0, 2]] <= w)
    assert np.all(segs[:, [1, 3]] >= -1) and np.all(segs[:, [1, 3]] <= h)
