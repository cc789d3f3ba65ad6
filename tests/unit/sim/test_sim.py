"""The renderer against the geometry by construction, the ground truth, determinism, and a small world."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.core import labels
from geoloc.core.camera import Intrinsics, vanishing_column_of_orientation, wrap_orientation_deg
from geoloc.core.geo import LocalFrame
from geoloc.maps import CityMap, load_map
from geoloc.maps.raycast import cast_panoramas
from geoloc.photos.exif import read_exif
from geoloc.sim import Pose, Render, Scene, render
from geoloc.sim.world import WorldOptions, camera_for, generate_world, load_world

INTR = Intrinsics.from_hfov(640, 480, 60.0)
ORIGIN = LocalFrame(60.17, 24.94)


def _box(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float]]:
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]


def _map(tmp_path: Path, boxes: list[tuple[list[tuple[float, float]], float]]) -> tuple[CityMap, np.ndarray]:
    """A GeoJSON map of box buildings given in ORIGIN's local frame; returns it and ORIGIN's offset in its frame."""
    features = []
    for i, (ring, height) in enumerate(boxes):
        xy = np.array(ring)
        lat, lon = ORIGIN.to_wgs84(xy[:, 0], xy[:, 1])
        features.append(
            {
                "type": "Feature",
                "id": f"way/{i + 1}",
                "properties": {"building": "yes", "height": height, "name": f"B{i}"},
                "geometry": {"type": "Polygon", "coordinates": [np.column_stack([lon, lat]).tolist()]},
            }
        )
    path = tmp_path / "boxes.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    city = load_map(path)
    return city, np.array(city.frame.to_local(ORIGIN.origin_lat, ORIGIN.origin_lon), dtype=float)


def _clean(scene: Scene, pose: Pose, intr: Intrinsics = INTR, **kw: Any) -> Render:
    return render(scene, pose, intr, photometric=False, occluders=False, **kw)


def test_box_building_columns_and_heights(tmp_path: Path) -> None:
    """A wall 30 m ahead, 8 m tall, with an 18 m tall building 50 m ahead behind it."""
    city, o = _map(tmp_path, [(_box(-10, 30, 10, 40), 8.0), (_box(-20, 50, 20, 60), 18.0)])
    scene = Scene(city, seed=3)
    r = _clean(scene, Pose(o[0], o[1], 0.0))
    f, cx, cy, h = INTR.focal_px, INTR.cx, INTR.cy, 1.6
    xc = np.arange(INTR.width) + 0.5
    yc = np.arange(INTR.height) + 0.5
    front = np.abs(xc - cx) < f * 10 / 30 - 0.5
    back = (np.abs(xc - cx) < f * 20 / 50 - 0.5) & ~(np.abs(xc - cx) < f * 10 / 30 + 0.5)
    edges = (np.abs(np.abs(xc - cx) - f * 10 / 30) < 1.0) | (np.abs(np.abs(xc - cx) - f * 20 / 50) < 1.0)
    # The front wall spans rows [cy - f (H - h) / z, cy + f h / z] exactly (pixel centres inside).
    top0, bot0 = cy - f * (8.0 - h) / 30, cy + f * h / 30
    top1 = cy - f * (18.0 - h) / 50
    expect = np.full((INTR.height, INTR.width), -1)
    expect[(yc[:, None] >= top1) & (yc[:, None] <= cy + f * h / 50) & (front | back)[None, :]] = 1
    expect[(yc[:, None] >= top0) & (yc[:, None] <= bot0) & front[None, :]] = 0
    ok = ~edges[None, :] & (np.abs(yc[:, None] - top0) > 0.5) & (np.abs(yc[:, None] - top1) > 0.5)
    got = r.building_id
    assert np.array_equal(got[ok], expect[ok])
    assert np.all(r.labels[got >= 0] == labels.BUILDING)
    # Per-column ground truth: the front wall faces the camera head-on (theta 0) at 30 m.
    assert np.all(r.column_building_id[front] == 0)
    np.testing.assert_allclose(
        r.column_distance_m[front] * np.cos(np.radians(INTR.column_angle_deg(xc[front]))), 30.0, atol=1e-3
    )
    np.testing.assert_allclose(r.column_theta_deg[front], 0.0, atol=1e-6)
    assert np.all(np.isnan(r.column_theta_deg[np.abs(xc - cx) > f * 20 / 50 + 1]))
    # Sky above the tall building, ground below the walls.
    assert np.all(r.labels[: int(top1) - 1, INTR.width // 2] == labels.SKY)
    assert np.all(r.labels[int(bot0) + 2 :, INTR.width // 2] == labels.ROAD)


def test_building_ids_agree_with_cast_panoramas(tmp_path: Path) -> None:
    boxes = [
        (_box(-30, 20, -5, 35), 10.0),
        (_box(0, 25, 20, 50), 18.0),
        (_box(25, 10, 45, 30), 14.0),
        (_box(-15, 60, 40, 75), 30.0),
    ]
    city, o = _map(tmp_path, boxes)
    scene = Scene(city, seed=1)
    pos = o + np.array([3.0, -4.0])
    yaw = 17.3
    r = _clean(scene, Pose(pos[0], pos[1], yaw))
    pano = cast_panoramas(city, pos[None], bearing_step_deg=0.05)
    bearing = (yaw + INTR.column_angle_deg(np.arange(INTR.width) + 0.5)) % 360.0
    idx = np.round(bearing / 0.05).astype(int) % pano.building_id.shape[1]
    expected = pano.building_id[0, idx]
    assert (expected >= 0).mean() > 0.5
    assert (r.column_building_id == expected).mean() > 0.99
    # The nearest facade of every column covers the horizon row.
    horizon = r.building_id[int(INTR.cy)]
    assert (horizon == expected).mean() > 0.99
    # Theta and distance match the panorama's nearest hit.
    hit = expected >= 0
    theta = wrap_orientation_deg(pano.normal_bearing_deg[0, idx] - yaw)
    same = hit & (r.column_building_id == expected)
    assert np.nanmax(np.abs(wrap_orientation_deg(r.column_theta_deg[same] - theta[same]))) < 1e-3
    assert np.max(np.abs(r.column_distance_m[same] - pano.distance_m[0, idx][same])) < 0.5


def _segments(rgb: np.ndarray) -> np.ndarray:
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    lines = cv2.createLineSegmentDetector().detect(gray)[0]
    return np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(float) + 0.5  # to our pixel centres


def _vanishing_point(seg: np.ndarray) -> np.ndarray:
    """Least-squares intersection of segment lines (weighted by length)."""
    p, q = seg[:, :2], seg[:, 2:]
    d = (q - p) / np.linalg.norm(q - p, axis=1, keepdims=True)
    n = np.column_stack([-d[:, 1], d[:, 0]])
    w = np.linalg.norm(q - p, axis=1)
    a = (n * w[:, None]).T @ n
    b = (n * w[:, None]).T @ np.einsum("ij,ij->i", n, p)
    return np.linalg.solve(a, b)


@pytest.mark.parametrize("yaw", [30.0, 150.0])
def test_facade_lines_meet_at_the_vanishing_point(tmp_path: Path, yaw: float) -> None:
    """A long wall seen obliquely: its window rows, bands and sills converge to the predicted vanishing point."""
    city, o = _map(tmp_path, [(_box(10, -150, 30, 150), 20.0)])
    scene = Scene(city, seed=5)
    r = _clean(scene, Pose(o[0], o[1], yaw))
    theta = float(wrap_orientation_deg(270.0 - yaw))
    x_vp = float(vanishing_column_of_orientation(theta, INTR))
    vp = np.array([x_vp, INTR.cy])
    seg = _segments(r.rgb)
    mid = ((seg[:, :2] + seg[:, 2:]) / 2).astype(int)
    inside = (mid[:, 0] >= 0) & (mid[:, 0] < INTR.width) & (mid[:, 1] >= 0) & (mid[:, 1] < INTR.height)
    seg, mid = seg[inside], mid[inside]
    on_building = r.labels[mid[:, 1], mid[:, 0]] == labels.BUILDING
    dx, dy = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    length = np.hypot(dx, dy)
    horizontal = on_building & (np.abs(dx) > 2 * np.abs(dy)) & (length > 25)
    assert horizontal.sum() >= 10
    seg = seg[horizontal]
    # Distance of the predicted vanishing point to each segment's line.
    d = seg[:, 2:] - seg[:, :2]
    n = np.column_stack([-d[:, 1], d[:, 0]]) / np.linalg.norm(d, axis=1, keepdims=True)
    dist = np.abs(np.einsum("ij,ij->i", n, vp - seg[:, :2]))
    # Each long segment points at the vanishing point to within half a pixel over its own length.
    reach = np.linalg.norm(vp - (seg[:, :2] + seg[:, 2:]) / 2, axis=1)
    length = np.linalg.norm(d, axis=1)
    long = length >= 80
    assert long.sum() >= 3 and np.max(dist[long] / reach[long] * length[long]) < 0.5
    fit = _vanishing_point(seg)  # all segments, weighted by length
    assert abs(fit[1] - INTR.cy) < 2.5
    assert abs(fit[0] - x_vp) < 2.5


def test_pitch_and_roll_are_a_rotation_homography(tmp_path: Path) -> None:
    city, o = _map(tmp_path, [(_box(-20, 20, 20, 40), 20.0)])
    scene = Scene(city, seed=2)
    upright = _clean(scene, Pose(o[0], o[1], 10.0))
    tilted = _clean(scene, Pose(o[0], o[1], 10.0, pitch_deg=3.0, roll_deg=2.0))
    # Pitch up moves the horizon down; the building is still where the rotation puts it.
    from geoloc.sim.pose import rotation_matrix

    k = INTR.matrix
    hmat = k @ rotation_matrix(3.0, 2.0) @ np.linalg.inv(k)
    shift = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])
    warped = cv2.warpPerspective(
        upright.labels, shift @ hmat @ np.linalg.inv(shift), (INTR.width, INTR.height), flags=cv2.INTER_NEAREST
    )
    valid = (
        cv2.warpPerspective(
            np.ones_like(upright.labels),
            shift @ hmat @ np.linalg.inv(shift),
            (INTR.width, INTR.height),
            flags=cv2.INTER_NEAREST,
        )
        > 0
    )
    assert (warped[valid] == tilted.labels[valid]).mean() > 0.99
    # Horizon straight ahead: the upright centre maps below the centre row when looking up.
    p = hmat @ np.array([INTR.cx, INTR.cy, 1.0])
    assert p[1] / p[2] > INTR.cy + INTR.focal_px * math.tan(math.radians(3.0)) * 0.9


def test_render_is_deterministic_and_looks_depend_on_building(tmp_path: Path) -> None:
    city, o = _map(tmp_path, [(_box(-25, 15, 0, 30), 15.0), (_box(0, 15, 25, 30), 15.0)])
    pose = Pose(o[0], o[1], 0.0)
    a = render(Scene(city, seed=4), pose, INTR, seed=9)
    b = render(Scene(city, seed=4), pose, INTR, seed=9)
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.labels, b.labels)
    c = render(Scene(city, seed=5), pose, INTR, seed=9)
    assert not np.array_equal(a.rgb, c.rgb)
    # The two identical boxes look different (their own looks), and the same from another viewpoint.
    left = a.rgb[a.building_id == 0].mean(axis=0)
    right = a.rgb[a.building_id == 1].mean(axis=0)
    assert np.abs(left - right).max() > 3 or a.rgb[a.building_id == 0].std() != a.rgb[a.building_id == 1].std()
    assert a.building_shares() and abs(sum(a.building_shares().values()) - (a.building_id >= 0).mean()) < 1e-9


def test_render_time_640x480(tmp_path: Path) -> None:
    import time

    city, o = _map(tmp_path, [(_box(-40 + 12 * i, 20, -30 + 12 * i, 35), 10.0 + 3 * i) for i in range(7)])
    scene = Scene(city, seed=1)
    render(scene, Pose(o[0], o[1], 0.0), INTR)
    t = time.perf_counter()
    render(scene, Pose(o[0] + 1, o[1], 5.0), INTR)
    assert time.perf_counter() - t < 1.0


def test_camera_for_uses_an_integer_35mm_focal() -> None:
    intr, f35, fmm = camera_for(640, 480, 60.0)
    assert f35 == 31 and abs(intr.hfov_deg - 60.0) < 0.5
    assert intr.focal_px == pytest.approx(31 / 36 * 640)
    assert fmm == pytest.approx(31 / 7, abs=0.01)


def test_small_world_writes_everything_and_is_deterministic(tmp_path: Path) -> None:
    boxes = [(_box(-40, 10 + 30 * i, -10, 35 + 30 * i), 12.0 + 4 * i) for i in range(3)]
    boxes += [(_box(10, 10 + 30 * i, 40, 35 + 30 * i), 20.0 - 3 * i) for i in range(3)]
    city, _ = _map(tmp_path, boxes)
    src = tmp_path / "boxes.geojson"
    opts = WorldOptions(n_references=3, n_queries=2, seed=7, width=320, height=240, radius_m=0.0)
    m1 = generate_world(src, tmp_path / "w1", opts, city_map=city)
    m2 = generate_world(src, tmp_path / "w2", opts, city_map=city)
    assert json.dumps(m1["images"]) == json.dumps(m2["images"])
    world = load_world(tmp_path / "w1")
    assert len(world.references) == 3 and len(world.queries) == 2
    assert (tmp_path / "w1" / "contact_sheet.jpg").stat().st_size > 0
    for im in world.images:
        assert im.path.exists()
        gt = world.gt(im.name)
        assert gt["labels"].shape == (240, 320) and gt["building_id"].shape == (240, 320)
        assert gt["column_theta_deg"].shape == (320,) and gt["column_distance_m"].shape == (320,)
        assert im.rgb().shape == (240, 320, 3)
        exif = read_exif(im.path)
        assert exif.focal_35mm == im.record["intrinsics"]["focal_35mm"]
        gps = im.record["gps"]
        assert exif.lat == pytest.approx(gps["lat"], abs=1e-8) and exif.lon == pytest.approx(gps["lon"], abs=1e-8)
        assert im.record["buildings"] and im.record["building_fraction"] > 0.2
        assert np.array_equal(gt["building_id"], np.load(tmp_path / "w2" / im.record["gt"])["building_id"])


def test_a_world_around_a_chosen_centre_samples_inside_its_disk_and_records_it(tmp_path: Path) -> None:
    src = shared_path("data", "osm", "helsinki.osm.pbf")
    centre = (60.174270, 24.945337)  # Kaisaniemi: far from the buildings' median, the default centre
    opts = WorldOptions(n_references=2, n_queries=1, seed=3, width=320, height=240, radius_m=60.0, centre_wgs84=centre)
    manifest = generate_world(src, tmp_path / "w", opts)
    assert list(manifest["options"]["centre_wgs84"]) == list(centre)
    assert manifest["region"]["centre_wgs84"] == pytest.approx(list(centre), abs=1e-9)
    cx, cy = manifest["region"]["centre_m"]
    for record in manifest["images"]:
        pose = record["pose"]
        assert math.hypot(pose["x_m"] - cx, pose["y_m"] - cy) <= 60.0 + 15.0, record["name"]  # queries sit off streets
    default = WorldOptions(n_references=2, n_queries=1, seed=3, width=320, height=240, radius_m=60.0)
    assert "centre_wgs84" not in generate_world(src, tmp_path / "d", default)["options"]
