"""Map anchors (keypoint rays meeting extruded facades) and absolute pose from 2D-3D matches."""

import numpy as np
import pytest

from geoloc.core.camera import Intrinsics
from geoloc.localize.absolute_pose import estimate_pose, estimate_pose_from_groups, project
from geoloc.localize.anchors import CameraPose, MapAnchors, anchor_keypoints
from geoloc.maps import city_map_from_footprints
from geoloc.vision.vp_geometry import rotation_upright_from_pitch_roll
from tests.scenes import box, square_building

INTRINSICS = Intrinsics.from_hfov(640, 480, 60.0)


def _grid_pixels(step: int = 40) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(20, 640, step), np.arange(20, 480, step))
    return np.column_stack([xs.ravel(), ys.ravel()]).astype(float)


def test_anchors_lie_on_the_wall_where_the_pinhole_model_puts_them() -> None:
    city = square_building()  # 20 m square, 15 m tall; its south wall is y = -10
    pose = CameraPose(0.0, -30.0, 0.0, 1.6)  # 20 m south of the wall, looking north, level
    pixels = _grid_pixels()
    anchors = anchor_keypoints(city, pose, INTRINSICS, pixels)
    f, cx, cy = INTRINSICS.focal_px, INTRINSICS.cx, INTRINSICS.cy
    x = (pixels[:, 0] - cx) / f * 20.0
    z = 1.6 - (pixels[:, 1] - cy) / f * 20.0
    expected_valid = (np.abs(x) <= 10.0) & (z >= 0.0) & (z <= 15.0 + 0.5)
    assert np.array_equal(anchors.valid, expected_valid)
    ok = anchors.valid
    assert np.allclose(anchors.xyz[ok, 0], x[ok], atol=1e-6)
    assert np.allclose(anchors.xyz[ok, 1], -10.0, atol=1e-6)
    assert np.allclose(anchors.xyz[ok, 2], np.minimum(z[ok], 15.0), atol=1e-6)
    assert np.allclose(anchors.distance_m[ok], np.hypot(x[ok], 20.0), rtol=1e-6)  # horizontal distance
    # Projecting the points back from the same pose gives the pixels they came from.
    back, depth = project(anchors.xyz[ok], pose, INTRINSICS)
    assert np.all(depth > 0)
    # Points clipped at the roof line (z capped at the top) do not come back exactly; the rest do.
    below_top = z[ok] <= 15.0
    assert np.allclose(back[below_top], pixels[ok][below_top], atol=1e-6)
    # Round trip through storage.
    again = MapAnchors.from_arrays(anchors.to_arrays())
    assert np.array_equal(again.valid, anchors.valid)


def test_rays_above_a_low_building_reach_the_tall_one_behind() -> None:
    low = box(-30, -12, 30, -10)  # 4 m tall wall-like building in front
    tall = box(-30, 10, 30, 20)  # 30 m tall block behind
    city = city_map_from_footprints([low, tall], heights_m=[4.0, 30.0])
    pose = CameraPose(0.0, -30.0, 0.0, 1.6)
    column = np.full(240, 320.0)
    rows = np.arange(240).astype(float)
    anchors = anchor_keypoints(city, pose, INTRINSICS, np.column_stack([column, rows]))
    hit_y = anchors.xyz[anchors.valid, 1]
    # Rows near the top of the image see the tall block (y = 10) over the low one (y = -12).
    assert set(np.round(hit_y).astype(int)) == {-12, 10}
    assert anchors.building_id[0] == 1 and anchors.building_id[-1] == 0


def _synthetic_correspondences(rng: np.random.Generator, pose: CameraPose, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points on the square's walls seen from a reference pose, and where ``pose`` sees them."""
    city = square_building()
    reference = CameraPose(-6.0, -35.0, 10.0, 1.6)
    pixels = rng.uniform([0, 0], [640, 480], size=(4 * n, 2))
    anchors = anchor_keypoints(city, reference, INTRINSICS, pixels)
    points = anchors.xyz[anchors.valid][:n]
    seen, depth = project(points, pose, INTRINSICS)
    inside = (depth > 0) & (seen[:, 0] >= 0) & (seen[:, 0] < 640) & (seen[:, 1] >= 0) & (seen[:, 1] < 480)
    return points[inside], seen[inside]


def test_pnp_recovers_a_pitched_pose_among_outliers() -> None:
    rng = np.random.default_rng(3)
    truth = CameraPose(5.0, -28.0, 352.0, 1.55, rotation_upright_from_pitch_roll(2.0, -0.5))
    points, pixels = _synthetic_correspondences(rng, truth, 120)
    pixels = pixels + rng.normal(0.0, 0.7, pixels.shape)
    outliers = rng.uniform([0, 0], [640, 480], size=(len(points), 2))  # as many wrong matches as right ones
    estimate = estimate_pose(np.vstack([points, points]), np.vstack([pixels, outliers]), INTRINSICS)
    assert estimate is not None
    assert np.hypot(estimate.pose.x_m - 5.0, estimate.pose.y_m + 28.0) < 0.15
    assert abs((estimate.pose.yaw_deg - 352.0 + 180) % 360 - 180) < 0.2
    assert abs(estimate.pose.height_m - 1.55) < 0.15
    assert estimate.pitch_deg == pytest.approx(2.0, abs=0.3) and estimate.roll_deg == pytest.approx(-0.5, abs=0.3)
    assert estimate.inliers[: len(points)].mean() > 0.9 and estimate.inliers[len(points) :].mean() < 0.1
    assert np.all(np.linalg.eigvalsh(estimate.covariance) > 0)
    # Too few correspondences: no pose rather than a guess.
    assert estimate_pose(points[:5], pixels[:5], INTRINSICS) is None


def test_groups_keep_a_good_reference_from_drowning_among_bad_ones() -> None:
    rng = np.random.default_rng(5)
    truth = CameraPose(-3.0, -31.0, 5.0, 1.6)
    points, pixels = _synthetic_correspondences(rng, truth, 40)
    good = (points, pixels + rng.normal(0.0, 0.5, pixels.shape))
    # Four other references whose matches are all wrong (repeated textures elsewhere), 10x as many.
    bad = [(points[rng.integers(0, len(points), 100)], rng.uniform([0, 0], [640, 480], (100, 2))) for _ in range(4)]
    estimate, owner = estimate_pose_from_groups([*bad[:2], good, *bad[2:]], INTRINSICS, min_inliers=20)
    assert estimate is not None
    assert np.hypot(estimate.pose.x_m + 3.0, estimate.pose.y_m + 31.0) < 0.2
    assert set(np.unique(owner[estimate.inliers]).tolist()) >= {2}
    assert estimate.inliers[owner == 2].mean() > 0.9
