"""Casting only the bearings a caller reads gives the full cast's bits, on the Helsinki map.

``cast_panoramas(..., bearing_indices=...)`` (the refinement's likelihood window, the vanishing-point bins) against
the full panorama at those bearings; the likelihood of :meth:`MapLikelihood.of_poses` (window-only casts, per-bearing
terms only where the window reads) against the likelihood of full panoramas; :func:`vanishing_point_yaw` against
its formulation on the full 0.1 deg panorama.
"""

from __future__ import annotations

import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.localize.likelihood import LikelihoodOptions, image_model_from_map
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.refinement import MIN_VP_BINS, VP_BEARING_STEP_DEG, VP_TOLERANCE_DEG, vanishing_point_yaw
from geoloc.maps import CityMap, load_map
from geoloc.maps.raycast import Panoramas, cast_panoramas, window_indices
from geoloc.vision.image_model import ImageModel

OFFSETS_DEG = np.arange(-65, 66) * 0.5  # a 65 deg camera's bins at 0.5 deg
REFINE_YAW_OFFSETS_DEG = np.array([-1.0, -0.5, 0.0, 0.5, 1.0])


@pytest.fixture(scope="module")
def city() -> CityMap:
    return load_map(shared_path("data", "osm", "helsinki.osm.pbf"))


@pytest.fixture(scope="module")
def streets(city: CityMap) -> np.ndarray:
    """(12, 2) positions outside buildings near the middle of the map."""
    rng = np.random.default_rng(3)
    candidates = rng.uniform(-300.0, 300.0, (400, 2))
    return candidates[~city.inside_buildings(candidates)][:12]


def _assert_same_at(full: Panoramas, part: Panoramas, bearings: np.ndarray) -> None:
    cast = np.unique(bearings % len(full.bearings_deg))
    assert np.isfinite(full.distance_m[:, cast]).mean() > 0.5  # the map is really around
    for name in ("facade_id", "building_id", "distance_m", "normal_bearing_deg"):
        assert np.array_equal(getattr(full, name)[:, cast], getattr(part, name)[:, cast], equal_nan=True), name
    others = np.setdiff1d(np.arange(len(full.bearings_deg)), cast)
    assert (part.facade_id[:, others] == -1).all() and np.isinf(part.distance_m[:, others]).all()


def test_window_cast_equals_full_cast(city: CityMap, streets: np.ndarray) -> None:
    fine = np.stack(np.meshgrid(np.arange(-6, 7.0), np.arange(-6, 7.0)), axis=-1).reshape(-1, 2)
    rng = np.random.default_rng(1)
    cases = [
        (fine + streets[0], 0.5),  # the refinement's grid (one tile)
        (streets[1] + rng.uniform(-150, 150, (200, 2)), 0.5),  # several tiles
        (streets[2:3], VP_BEARING_STEP_DEG),  # the vanishing-point yaw
        (streets, 1.0),
    ]
    for positions, step in cases:
        n_bearings = int(round(360.0 / step))
        full = cast_panoramas(city, positions, bearing_step_deg=step)
        windows = [window_indices(n_bearings, yaw + REFINE_YAW_OFFSETS_DEG, OFFSETS_DEG) for yaw in (0.3, 181.0, 359.7)]
        windows.append(window_indices(n_bearings, np.array([90.0]), np.arange(-100, 101) * 1.0))  # > 170 deg: no cull
        windows.append(rng.choice(n_bearings, 40, replace=False))  # scattered bearings
        for bearings in windows:
            part = cast_panoramas(city, positions, bearing_step_deg=step, bearing_indices=bearings)
            _assert_same_at(full, part, bearings)


def _image_model(city: CityMap, position: np.ndarray, yaw_deg: float) -> ImageModel:
    """A perfect model at a pose, blurred: fractional confidences, identities, distances and building tops."""
    panorama = cast_panoramas(city, position[None], bearing_step_deg=0.5)
    truth = image_model_from_map(panorama, 0, yaw_deg, OFFSETS_DEG, with_distance=True)
    assert truth.identity_prob is not None and truth.distance_m is not None
    rng = np.random.default_rng(7)
    present = truth.facade_present * rng.uniform(0.5, 1.0, truth.n_bins)
    building = panorama.building_id[0, window_indices(720, np.array([yaw_deg]), OFFSETS_DEG)[0]]
    height = np.where(building >= 0, city.known_building_height_m[np.maximum(building, 0)], np.nan)
    tops = (height - 1.6) / np.maximum(truth.distance_m, 0.1)  # NaN where unknown: the skyline term where known
    return ImageModel(
        OFFSETS_DEG,
        present,
        truth.orientation_deg + rng.normal(0.0, 2.0, truth.n_bins),
        truth.identity_building_ids,
        0.8 * truth.identity_prob,
        truth.distance_m * rng.uniform(0.8, 1.3, truth.n_bins),
        tops,
        0.5,
    )


def test_likelihood_of_window_casts_equals_full_panoramas(city: CityMap, streets: np.ndarray) -> None:
    fine = np.stack(np.meshgrid(np.arange(-6, 7.0), np.arange(-6, 7.0)), axis=-1).reshape(-1, 2)
    compared = skyline = 0
    for position, yaw in zip(streets[:3], (20.0, 200.0, 359.5), strict=True):
        model = _image_model(city, position, yaw)
        assert model.top_tan_elevation is not None
        skyline += int(np.isfinite(model.top_tan_elevation).any())
        positions = fine + position
        for options in (LikelihoodOptions(), LikelihoodOptions(use_identity=False, normalization="paper")):
            likelihood = MapLikelihood(city, model, options)
            for yaws in (yaw + REFINE_YAW_OFFSETS_DEG, np.array([yaw + 3.0]), np.arange(120) * 3.0):
                fast = likelihood.of_poses(positions, yaws)
                plain = likelihood.of_panoramas(likelihood.panoramas(positions), yaws)
                assert plain.max() > 0.05
                assert np.array_equal(fast, plain)
                compared += 1
    assert compared == 3 * 2 * 3 and skyline > 0


def _vanishing_point_yaw_full(
    city: CityMap, model: ImageModel, x_m: float, y_m: float, yaw_deg: float
) -> tuple[float, int]:
    """:func:`vanishing_point_yaw` as it was: the full 0.1 deg panorama, read at the bins."""
    present = model.facade_present > 0
    panorama = cast_panoramas(city, np.array([[x_m, y_m]]), bearing_step_deg=VP_BEARING_STEP_DEG)
    n_bearings = panorama.normal_bearing_deg.shape[1]
    yaw, support = float(yaw_deg), 0
    for _ in range(2):
        index = np.round(((yaw + model.offsets_deg) % 360.0) / VP_BEARING_STEP_DEG).astype(np.int64) % n_bearings
        normal = panorama.normal_bearing_deg[0, index]
        delta = ((normal - model.orientation_deg) - yaw + 90.0) % 180.0 - 90.0
        agree = present & np.isfinite(delta) & (np.abs(delta) < VP_TOLERANCE_DEG)
        support = int(agree.sum())
        if support < MIN_VP_BINS:
            return yaw_deg % 360.0, 0
        yaw += float(np.median(delta[agree]))
    return yaw % 360.0, support


def test_vanishing_point_yaw_equals_full_panorama(city: CityMap, streets: np.ndarray) -> None:
    refined = 0
    for position, yaw in zip(streets[:6], (20.0, 200.0, 359.5, 0.2, 91.0, 270.0), strict=True):
        model = _image_model(city, position, yaw)
        for start_yaw in (yaw, yaw + 4.3, yaw - 7.9):
            for x, y in (position, position + 1.5):
                fast = vanishing_point_yaw(city, model, float(x), float(y), start_yaw)
                assert fast == _vanishing_point_yaw_full(city, model, float(x), float(y), start_yaw)
                refined += fast[1] > 0
    assert refined > 20  # the yaw is really refined, not only left as it was
