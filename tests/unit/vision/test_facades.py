"""Facade decomposition on a synthetic two-facade corner, orientation conventions, evaluation."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from geoloc.core.camera import Intrinsics, orientation_from_vanishing_column, vanishing_column_of_orientation
from geoloc.core.labels import BUILDING, ROAD, SKY
from geoloc.evaluation.facades import orientation_errors
from geoloc.vision.facades import analyze_image, facade_image_model
from geoloc.vision.image_model import image_model_from_columns

CAMERA_HEIGHT_M = 1.6


def _project(points_cam: np.ndarray, intr: Intrinsics) -> np.ndarray:
    p = points_cam @ intr.matrix.T
    return p[:, :2] / p[:, 2:3]


def render_walls(
    walls: list[tuple[np.ndarray, float, float, tuple[int, int, int]]],
    intr: Intrinsics,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Render upright-camera views of vertical walls with window rows (OpenCV drawing).

    walls: (start point (x, z) in the camera frame, along-wall bearing theta_deg (the wall's
    orientation, see geoloc.core.camera), length m, RGB colour). Returns (image RGB uint8, labels).
    The walls go from 10 m above the camera down to the ground (1.6 m below it).
    """
    import cv2

    h, w = intr.height, intr.width
    img = np.zeros((h, w, 3), np.uint8)
    labels = np.full((h, w), SKY, np.uint8)
    horizon = round(intr.cy)
    img[:horizon] = (150, 190, 235)
    img[horizon:] = (110, 110, 115)
    labels[horizon:] = ROAD
    scale = 8  # sub-pixel drawing precision
    for start_xz, theta_deg, length_m, colour in walls:
        t = math.radians(theta_deg)
        u = np.array([math.cos(t), 0.0, -math.sin(t)])
        p0 = np.array([start_xz[0], 0.0, start_xz[1]])

        def pt(s: float, y: float, u: np.ndarray = u, p0: np.ndarray = p0) -> np.ndarray:
            return p0 + s * u + np.array([0.0, y, 0.0])

        quad = np.array([pt(0, -10), pt(length_m, -10), pt(length_m, CAMERA_HEIGHT_M), pt(0, CAMERA_HEIGHT_M)])
        poly = np.round(_project(quad, intr) * scale).astype(np.int32)
        cv2.fillPoly(img, [poly], colour, lineType=cv2.LINE_AA, shift=3)
        cv2.fillPoly(labels, [poly], BUILDING, shift=3)
        dark = tuple(int(c * 0.35) for c in colour)
        for s in np.arange(1.0, length_m - 1.5, 2.6):
            for y in np.arange(-9.0, 0.0, 3.0):
                win = np.array([pt(s, y), pt(s + 1.3, y), pt(s + 1.3, y + 1.7), pt(s, y + 1.7)])
                wp = np.round(_project(win, intr) * scale).astype(np.int32)
                cv2.fillPoly(img, [wp], dark, lineType=cv2.LINE_AA, shift=3)
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(img, (3, 3), 0.7)
    img = np.clip(img.astype(float) + rng.normal(0, 3.0, img.shape), 0, 255).astype(np.uint8)
    return img, labels


INTR = Intrinsics.from_hfov(800, 600, 60.0)
THETA_LEFT, THETA_RIGHT = 35.0, -50.0
CORNER_XZ = np.array([0.8, 14.0])


def corner_scene() -> tuple[np.ndarray, np.ndarray, float]:
    """Convex building corner in front of the camera; returns image, labels, corner column (px).

    A wall receding to the left (theta 35 deg) and one receding to the right (theta -50 deg).
    """
    # Left wall drawn from its far end towards the corner, right wall from the corner outwards.
    t_l = math.radians(THETA_LEFT)
    u_l = np.array([math.cos(t_l), -math.sin(t_l)])  # (x, z) along-wall, pointing right/closer
    far_left = CORNER_XZ - 30.0 * u_l
    walls = [
        (far_left, THETA_LEFT, 30.0, (205, 180, 150)),
        (CORNER_XZ, THETA_RIGHT, 30.0, (165, 140, 120)),
    ]
    img, labels = render_walls(walls, INTR)
    corner_col = INTR.cx + INTR.focal_px * CORNER_XZ[0] / CORNER_XZ[1]
    return img, labels, corner_col


def test_two_facade_corner_decomposes_into_two_pieces() -> None:
    img, labels, corner_col = corner_scene()
    analysis = analyze_image(img, labels, INTR)
    pieces = sorted(analysis.decomposition.pieces, key=lambda p: p.x_start)
    assert len(pieces) == 2, [p.to_dict() for p in pieces]
    left, right = pieces
    assert abs(left.theta_deg - THETA_LEFT) < 2.0
    assert abs(right.theta_deg - THETA_RIGHT) < 2.0
    assert abs(left.x_end - corner_col) < 0.02 * INTR.width
    assert right.x_start == left.x_end
    # The image model carries the orientations per angular bin.
    model = analysis.image_model
    alpha_corner = float(INTR.column_angle_deg(corner_col))
    left_bins = (model.offsets_deg < alpha_corner - 3) & (model.facade_present > 0)
    right_bins = (model.offsets_deg > alpha_corner + 3) & (model.facade_present > 0)
    assert left_bins.sum() > 10 and right_bins.sum() > 10
    assert np.all(np.abs(model.orientation_deg[left_bins] - THETA_LEFT) < 2.0)
    assert np.all(np.abs(model.orientation_deg[right_bins] - THETA_RIGHT) < 2.0)
    # The horizon is level: no pitch or roll.
    assert abs(analysis.vanishing_points.pitch_deg) < 0.5
    assert abs(analysis.vanishing_points.roll_deg) < 0.5


def test_head_on_wall_gives_theta_zero_and_matches_camera_conventions() -> None:
    walls = [(np.array([-20.0, 12.0]), 0.0, 40.0, (190, 170, 150))]
    img, labels = render_walls(walls, INTR)
    model, deco = facade_image_model(labels, img, INTR)
    assert len(deco.pieces) == 1
    assert abs(deco.pieces[0].theta_deg) < 1.5
    assert np.mean(model.facade_present > 0) > 0.9
    # camera.py conventions: a VP at infinity is theta 0; VP columns and theta are inverses.
    assert orientation_from_vanishing_column(np.inf, INTR) == 0.0
    for theta in (-80.0, -35.0, 20.0, 60.0):
        x_vp = vanishing_column_of_orientation(theta, INTR)
        assert abs(float(orientation_from_vanishing_column(x_vp, INTR)) - theta) < 1e-9


def test_segments_on_non_building_pixels_are_ignored() -> None:
    img, labels, _ = corner_scene()
    no_building = np.where(labels == BUILDING, SKY, labels).astype(np.uint8)
    model, deco = facade_image_model(no_building, img, INTR)
    assert deco.pieces == []
    assert not deco.building_segments.any()
    assert np.all(model.facade_present == 0)


def test_orientation_errors() -> None:
    w = INTR.width
    gt_theta = np.where(np.arange(w) < w // 2, 30.0, -60.0)
    gt_building = np.arange(w) > w // 10  # the first tenth is not building
    present = np.where(np.arange(w) < 0.8 * w, 1.0, 0.0)
    pred_theta = gt_theta + np.where(np.arange(w) % 2 == 0, 3.0, 8.0)
    pred_theta[np.arange(w) < w // 4] = gt_theta[0] + 180.0 - 1.0  # modulo 180: 1 deg off
    model = image_model_from_columns(INTR, present, pred_theta)
    err = orientation_errors(model, gt_theta, gt_building, INTR)
    assert 0.7 < err.coverage < 0.8
    assert err.within_10deg > 0.95
    assert 0.2 < err.within_5deg < 0.7
    assert 1.0 <= err.median_abs_error_deg <= 8.0
    perfect = orientation_errors(image_model_from_columns(INTR, np.ones(w), gt_theta), gt_theta, gt_building, INTR)
    assert perfect.median_abs_error_deg == pytest.approx(0.0, abs=0.6)  # bins straddling the step
    assert perfect.coverage == pytest.approx(1.0)


def test_analyze_command_writes_overlays(tmp_path: Path) -> None:
    from PIL import Image
    from typer.testing import CliRunner

    from cli.main import app

    img, labels, _ = corner_scene()
    image_path, labels_path = tmp_path / "corner.png", tmp_path / "corner_labels.png"
    Image.fromarray(img).save(image_path)
    Image.fromarray(labels).save(labels_path)
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["analyze", str(image_path), "--out", str(out), "--hfov", "60", "--labels", str(labels_path)]
    )
    assert result.exit_code == 0, result.output
    for kind in ("segmentation", "lines", "facades", "birdseye", "overview"):
        assert (out / f"corner_{kind}.png").stat().st_size > 1000

    summary = json.loads((out / "corner_summary.json").read_text())
    thetas = sorted(p["theta_deg"] for p in summary["facades"]["pieces"])
    assert len(thetas) == 2 and abs(thetas[0] - THETA_RIGHT) < 2 and abs(thetas[1] - THETA_LEFT) < 2
    assert summary["intrinsics"]["source"] == "given"
    bad = CliRunner().invoke(app, ["analyze", str(labels_path.with_suffix(".txt")), "--out", str(out)])
    assert bad.exit_code != 0
