import numpy as np
import pytest

from geoloc.core.camera import wrap_orientation_deg
from geoloc.maps.raycast import cast_all_hits, cast_panoramas, panorama_window
from tests.scenes import l_shaped_building, square_building, street_canyon


def _at(pano, bearing_deg: float) -> int:
    return int(round(bearing_deg / pano.bearing_step_deg)) % len(pano.bearings_deg)


def test_square_front_facade_distances_and_extent() -> None:
    city = square_building()
    pano = cast_panoramas(city, np.array([[0.0, -30.0]]))
    south = int(np.flatnonzero(np.isclose(city.facades.normal_bearing_deg, 180.0))[0])
    half_width_deg = np.degrees(np.arctan(10 / 20))  # 26.57: the wall's ends seen from 20 m
    for bearing in np.arange(-26.0, 26.5, 0.5):
        i = _at(pano, bearing)
        assert pano.facade_id[0, i] == south and pano.building_id[0, i] == 0
        assert pano.distance_m[0, i] == pytest.approx(20.0 / np.cos(np.radians(bearing)), abs=0.011)
        assert pano.normal_bearing_deg[0, i] == pytest.approx(180.0)
    for bearing in (half_width_deg + 0.5, -half_width_deg - 0.5, 90.0, 180.0, 270.0):
        i = _at(pano, bearing)
        assert pano.facade_id[0, i] == -1 and np.isinf(pano.distance_m[0, i])


def test_l_shape_concave_corner() -> None:
    city = l_shaped_building()
    pano = cast_panoramas(city, np.array([[25.0, 25.0]]))
    cases = {180.0: (15.0, 0.0), 270.0: (15.0, 90.0), 200.0: (15.0 / np.cos(np.radians(20)), 0.0)}
    for bearing, (distance, normal) in cases.items():
        i = _at(pano, bearing)
        assert pano.distance_m[0, i] == pytest.approx(distance, abs=0.011)
        assert pano.normal_bearing_deg[0, i] == pytest.approx(normal, abs=1e-4)
    # Looking north-east from the corner nothing is in the way.
    assert pano.facade_id[0, _at(pano, 45.0)] == -1


def test_street_canyon_occlusion_and_side_street() -> None:
    city = street_canyon()
    pano = cast_panoramas(city, np.array([[0.0, 0.0]]))
    # 20 deg right of north the ray meets x = 10 at y = 10 / tan(20) = 27.5: past the middle block
    # (y <= 15), on the west wall of the north-east block (y >= 20).
    i = _at(pano, 20.0)
    assert pano.distance_m[0, i] == pytest.approx(10 / np.sin(np.radians(20)), abs=0.011)
    assert pano.normal_bearing_deg[0, i] == pytest.approx(270.0)
    # 31 deg: y = 16.6 falls in the side street between blocks; the ray reaches the south face (y = 20)
    # of the north-east block, farther than the walls around it.
    i = _at(pano, 31.0)
    assert pano.distance_m[0, i] == pytest.approx(20 / np.cos(np.radians(31)), abs=0.011)
    assert pano.normal_bearing_deg[0, i] == pytest.approx(180.0)
    # West wall at bearing 270: 10 m, facing east; seen edge-on by a camera looking north.
    i = _at(pano, 270.0)
    assert pano.distance_m[0, i] == pytest.approx(10.0, abs=0.011)
    assert wrap_orientation_deg(pano.normal_bearing_deg[0, i] - 0.0) == pytest.approx(-90.0)


def test_many_positions_match_single_casts() -> None:
    city = street_canyon()
    rng = np.random.default_rng(0)
    positions = np.column_stack([rng.uniform(-9, 9, 50), rng.uniform(-80, 80, 50)])
    together = cast_panoramas(city, positions, chunk_m=25.0)
    for p in (0, 17, 49):
        alone = cast_panoramas(city, positions[p : p + 1])
        assert np.array_equal(alone.facade_id[0], together.facade_id[p])


def test_all_hits_agree_with_nearest_hit() -> None:
    city = street_canyon()
    pano = cast_panoramas(city, np.array([[0.0, 0.0]]))
    ray, facade, distance, along = cast_all_hits(city, np.array([0.0, 0.0]), pano.bearings_deg)
    first = np.r_[True, ray[1:] != ray[:-1]]
    nearest = np.full(len(pano.bearings_deg), -1)
    nearest[ray[first]] = facade[first]
    assert np.array_equal(nearest, pano.facade_id[0])
    assert np.all(np.diff(distance)[ray[1:] == ray[:-1]] >= 0)
    # The along-wall position of each hit lies on its facade, and the hit point is where the ray says.
    f = city.facades
    assert np.all((along >= 0) & (along <= f.length_m[facade] + 1e-9))
    direction = (f.end - f.start) / f.length_m[:, None]
    hit = f.start[facade] + along[:, None] * direction[facade]
    bearing = np.radians(pano.bearings_deg[ray])
    assert np.allclose(hit, distance[:, None] * np.column_stack([np.sin(bearing), np.cos(bearing)]), atol=1e-6)


def test_window_is_a_slice_of_bearings() -> None:
    city = square_building()
    pano = cast_panoramas(city, np.array([[0.0, -30.0]]))
    window = panorama_window(pano, np.array([0.0, 90.0, 358.5]), np.array([-1.0, 0.0, 1.5]))
    assert window.tolist() == [[718, 0, 3], [178, 180, 183], [715, 717, 0]]
