"""Pure speed-ups give the results of the formulations they replace, on real inputs.

The Helsinki map and the photos of a small simulated world (ground-truth labels, so no network is needed):
compiled kernels against their numpy specifications (ray casting, the pose likelihood), and reformulated
numpy against the code it replaced (marginalised identities, matching).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.localize.identity import IdentityMap
from geoloc.localize.labeling import column_building_ids, pose_identities
from geoloc.localize.likelihood import (
    LikelihoodOptions,
    default_yaws_deg,
    image_model_from_map,
    known_building_heights,
    pose_likelihood,
)
from geoloc.localize.likelihood_reference import pose_likelihood_numpy
from geoloc.localize.posterior import grid_around
from geoloc.maps import CityMap, raycast, raycast_reference
from geoloc.photos.photo import Photo, load_photo
from geoloc.sim.world import WorldOptions, generate_world, load_world
from geoloc.vision.evidence import PhotoEvidence, analyze_photo
from workers.context import method_context

pytestmark = pytest.mark.slow  # a rendered world and the numpy formulations: about a minute


@dataclass
class Scene:
    city: CityMap
    photos: list[tuple[np.ndarray, PhotoEvidence, Photo]]  # (gps_xy, evidence, photo)


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Scene:
    out = tmp_path_factory.mktemp("speedup-world")
    generate_world(
        shared_path("data", "osm", "helsinki.osm.pbf"),
        out,
        WorldOptions(n_references=3, n_queries=3, seed=5, radius_m=150.0),
    )
    world = load_world(Path(out))
    city = world.load_map()
    photos: list[tuple[np.ndarray, PhotoEvidence, Photo]] = []
    for image in [*world.references, *world.queries]:
        photo = load_photo(image.path)
        evidence = analyze_photo(photo, world.gt(image.name)["labels"], context=method_context())
        assert photo.gps is not None
        photos.append((np.array(city.frame.to_local(*photo.gps), dtype=np.float64), evidence, photo))
    return Scene(city, photos)


def _numpy_cast(city: CityMap, positions: np.ndarray, step: float) -> raycast.Panoramas:
    kernel = raycast._cast_tile
    raycast._cast_tile = raycast_reference.cast_tile_numpy
    try:
        return raycast.cast_panoramas(city, positions, bearing_step_deg=step)
    finally:
        raycast._cast_tile = kernel


def test_ray_casting_kernel_equals_numpy(scene: Scene) -> None:
    rng = np.random.default_rng(0)
    centres = np.array([xy for xy, _, _ in scene.photos])
    # Fine grids around the photos (refinement), scattered positions over 300 m (search grids, several tiles),
    # and one position at 0.1 deg bearings (the vanishing-point yaw).
    offsets = np.stack(np.meshgrid(np.arange(-6, 7.0), np.arange(-6, 7.0)), axis=-1).reshape(-1, 2)
    cases = [
        (offsets + centres[0], 0.5),
        (centres[1] + rng.uniform(-150, 150, (300, 2)), 0.5),
        (centres[2:3], 0.1),
        (centres, 1.0),
    ]
    for positions, step in cases:
        fast = raycast.cast_panoramas(scene.city, positions, bearing_step_deg=step)
        slow = _numpy_cast(scene.city, positions, step)
        assert np.isfinite(slow.distance_m).mean() > 0.5  # the map is really around
        assert np.array_equal(fast.facade_id, slow.facade_id)
        assert np.array_equal(fast.distance_m, slow.distance_m)
        assert np.array_equal(fast.building_id, slow.building_id)
        assert np.array_equal(fast.normal_bearing_deg, slow.normal_bearing_deg, equal_nan=True)


def test_likelihood_kernel_equals_numpy(scene: Scene) -> None:
    heights = known_building_heights(scene.city)
    assert np.isfinite(heights).any()  # the skyline term is exercised
    compared = 0
    for gps_xy, evidence, _ in scene.photos:
        grid = grid_around(scene.city, (float(gps_xy[0]), float(gps_xy[1])), 30.0, 5.0)
        model = evidence.image_model
        panoramas = raycast.cast_panoramas(scene.city, grid.positions, bearing_step_deg=model.bin_deg)
        # An identity-aware model: the map's identities at a grid pose, over the photo's own geometry.
        truth = image_model_from_map(panoramas, len(panoramas) // 2, 40.0, model.offsets_deg)
        assert truth.identity_prob is not None
        with_identity = type(model)(
            model.offsets_deg,
            model.facade_present,
            model.orientation_deg,
            truth.identity_building_ids,
            0.8 * truth.identity_prob,
            model.distance_m,
            model.top_tan_elevation,
            model.bin_deg,
        )
        yaw_sets = [default_yaws_deg(120), 103.27 + np.array([-1.0, -0.5, 0.0, 0.5, 1.0])]
        for yaws in yaw_sets:
            for options in (
                {"use_identity": False},
                {"use_identity": False, "building_height_m": heights},
                {"use_identity": False, "building_height_m": heights, "normalization": "paper"},
                {"use_identity": False, "use_distance": False},
                {"use_identity": True, "building_height_m": heights, "unknown_weight": 0.3},
            ):
                image_model = with_identity if options["use_identity"] else model
                keywords = dict(options)
                heights_or_none = keywords.pop("building_height_m", None)
                likelihood_options = LikelihoodOptions(**keywords)
                fast = pose_likelihood(panoramas, image_model, yaws, likelihood_options, heights_or_none)
                slow = pose_likelihood_numpy(panoramas, image_model, yaws, likelihood_options, heights_or_none)
                assert fast.shape == slow.shape and fast.dtype == slow.dtype
                assert slow.max() > 0.05
                np.testing.assert_allclose(fast, slow, rtol=0, atol=2e-6)
                # The best pose is the same up to near-ties (two poses within float32 rounding of each other).
                assert slow.ravel()[np.argmax(fast)] >= slow.max() - 2e-6
                compared += 1
    assert compared == 6 * 2 * 5


def _identity_from_poses_reference(column_ids: np.ndarray, weights: np.ndarray, mask: np.ndarray) -> IdentityMap:
    """The code :func:`geoloc.localize.labeling.pose_identities` replaced (np.add.at over every pose and column)."""
    ids = np.unique(column_ids[column_ids >= 0])
    width = column_ids.shape[1]
    prob = np.zeros((width, len(ids)), dtype=float)
    total = weights.sum()
    if len(ids) and total > 0:
        slot = np.searchsorted(ids, column_ids)
        valid = column_ids >= 0
        cols = np.broadcast_to(np.arange(width)[None, :], column_ids.shape)
        w = np.broadcast_to(weights[:, None], column_ids.shape)
        np.add.at(prob, (cols[valid], slot[valid]), w[valid])
        prob /= total
    return IdentityMap(ids, prob, mask)


def test_pose_identities_equal_the_per_column_sum(scene: Scene) -> None:
    rng = np.random.default_rng(1)
    for gps_xy, evidence, photo in scene.photos:
        grid = grid_around(scene.city, (float(gps_xy[0]), float(gps_xy[1])), 10.0, 2.0)
        model = evidence.image_model
        panoramas = raycast.cast_panoramas(scene.city, grid.positions, bearing_step_deg=model.bin_deg)
        yaws = default_yaws_deg(120)
        likelihood = pose_likelihood(panoramas, model.without_identity(), yaws).astype(float)
        weights = np.power(likelihood, 8.0)
        weights[rng.random(weights.shape) < 0.7] = 0.0  # most poses outside the chosen mode weigh nothing
        column_ids = column_building_ids(panoramas, yaws, photo.intrinsics, model.offsets_deg, model.bin_deg)
        expected = _identity_from_poses_reference(
            column_ids.reshape(-1, column_ids.shape[-1]), weights.ravel(), evidence.building_mask
        )
        got = pose_identities(panoramas, yaws, photo.intrinsics, model, weights, evidence.building_mask)
        assert len(expected.building_ids) >= 2
        assert np.array_equal(got.building_ids, expected.building_ids)
        assert np.array_equal(got.column_prob, expected.column_prob)  # bit for bit
