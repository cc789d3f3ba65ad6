import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geoloc.core.camera import Intrinsics
from geoloc.localize.likelihood import LikelihoodOptions, default_yaws_deg, image_model_from_map, pose_likelihood
from geoloc.localize.posterior import grid_around, pose_posterior, position_heatmap, top_poses
from geoloc.maps import city_map_from_footprints
from geoloc.maps.raycast import Panoramas, cast_panoramas
from geoloc.vision.image_model import ImageModel, bin_offsets_deg
from tests.scenes import l_shaped_building, square_building, street_canyon, twin_buildings

OFFSETS = bin_offsets_deg(Intrinsics.from_hfov(640, 480, 60.0))
YAWS = default_yaws_deg(120)


def _setup(city, center, half_size_m, true_xy, true_yaw, with_identity=True):
    grid = grid_around(city, center, half_size_m, 10.0)
    positions = grid.positions
    pano = cast_panoramas(city, positions)
    true_index = int(np.flatnonzero(np.all(np.isclose(positions, true_xy), axis=1))[0])
    model = image_model_from_map(pano, true_index, true_yaw, OFFSETS, with_identity=with_identity)
    return grid, pano, true_index, model


def _yaw_index(yaw: float) -> int:
    return int(np.flatnonzero(np.isclose(YAWS, yaw))[0])


@pytest.mark.parametrize(
    ("scene", "center", "true_xy", "true_yaw"),
    [
        (square_building, (0.0, 0.0), (0.0, -30.0), 0.0),
        (l_shaped_building, (20.0, 20.0), (30.0, 20.0), 201.0),
        (street_canyon, (0.0, 0.0), (0.0, -10.0), 0.0),
        (street_canyon, (0.0, 0.0), (0.0, 30.0), 150.0),
    ],
)
def test_true_pose_is_the_maximum_for_a_clean_model(scene, center, true_xy, true_yaw) -> None:
    city = scene()
    _, pano, true_index, model = _setup(city, center, 60.0, true_xy, true_yaw)
    for use_identity in (False, True):
        lik = pose_likelihood(pano, model, YAWS, LikelihoodOptions(use_identity=use_identity))
        assert lik[true_index, _yaw_index(true_yaw)] == pytest.approx(1.0, abs=1e-5)
        assert lik.max() <= 1.0 + 1e-6
        # The image carries no depth, so a pose can tie only if it shows exactly the same view (e.g. a
        # step along the line of sight into a corner): the same facades' bins, the same orientations.
        for p, y in zip(*np.nonzero(lik > 1.0 - 1e-4), strict=True):
            other = image_model_from_map(pano, int(p), float(YAWS[y]), OFFSETS)
            assert np.array_equal(other.facade_present, model.facade_present)
            on = model.facade_present > 0
            delta = (other.orientation_deg[on] - model.orientation_deg[on] + 90) % 180 - 90
            assert np.abs(delta).max() < 1e-3


def test_paper_normalisation_scores_mean_weight_at_true_pose() -> None:
    city = square_building()
    _, pano, true_index, model = _setup(city, (0.0, 0.0), 60.0, (0.0, -30.0), 0.0)
    lik = pose_likelihood(pano, model, YAWS, LikelihoodOptions(normalization="paper", sigma_m=40.0))
    window = pano.distance_m[true_index][np.round(OFFSETS / 0.5).astype(int) % 720]
    expected = np.mean(np.exp(-(window[np.isfinite(window)] ** 2) / (2 * 40.0**2)))
    assert lik[true_index, 0] == pytest.approx(expected, rel=1e-4)


def test_square_is_ambiguous_by_symmetry() -> None:
    city = square_building()
    _, pano, _, model = _setup(city, (0.0, 0.0), 60.0, (0.0, -30.0), 0.0)
    lik = pose_likelihood(pano, model, YAWS, LikelihoodOptions(use_identity=False))
    positions = pano.positions
    # The square looks the same from its four sides: four equal peaks, 90 deg apart.
    for xy, yaw in (((0, -30), 0.0), ((30, 0), 270.0), ((0, 30), 180.0), ((-30, 0), 90.0)):
        index = int(np.flatnonzero(np.all(np.isclose(positions, xy), axis=1))[0])
        assert lik[index, _yaw_index(yaw)] == pytest.approx(1.0, abs=1e-5)


def _twins() -> tuple[Panoramas, int, int]:
    """Panoramas over the twin buildings and the grid indices of a pose at the West one and of its twin pose.

    The camera (yaw 201 deg) looks south-west into the concave corner of the West building; its twin pose is 200 m
    east.
    """
    city = twin_buildings()
    pano = cast_panoramas(city, grid_around(city, (20.0, 20.0), 150.0, 10.0).positions)
    true_index, twin_index = (
        int(np.flatnonzero(np.all(np.isclose(pano.positions, xy), axis=1))[0]) for xy in ((-70.0, 20.0), (130.0, 20.0))
    )
    return pano, true_index, twin_index


def test_identity_breaks_the_tie_between_twin_buildings() -> None:
    pano, true_index, twin_index = _twins()
    model = image_model_from_map(pano, true_index, 201.0, OFFSETS, with_identity=True)
    assert model.identity_building_ids.tolist() == [0]
    yaw = _yaw_index(201.0)
    geometry = pose_likelihood(pano, model, YAWS, LikelihoodOptions(use_identity=False))
    identity = pose_likelihood(pano, model, YAWS, LikelihoodOptions(use_identity=True))
    assert geometry[true_index, yaw] == pytest.approx(geometry[twin_index, yaw], abs=1e-6) == pytest.approx(1.0)
    assert identity[true_index, yaw] == pytest.approx(1.0, abs=1e-5)
    assert identity[twin_index, yaw] == pytest.approx(0.0, abs=1e-6)
    # Identity-aware: every top answer is at the West building; geometry alone splits between the twins.
    x_identity = [r.x_m for r in top_poses(pano.positions, pose_posterior(identity), YAWS, n=3)]
    x_geometry = [r.x_m for r in top_poses(pano.positions, pose_posterior(geometry), YAWS, n=6)]
    assert all(x < 0 for x in x_identity)
    assert any(x < 0 for x in x_geometry) and any(x > 0 for x in x_geometry)


def test_identity_trust_runs_from_the_identity_aware_likelihood_to_the_geometry_only_one() -> None:
    pano, true_index, twin_index = _twins()
    # The identities name the East twin while the camera looks at the West one: wrong identities.
    wrong = image_model_from_map(pano, twin_index, 201.0, OFFSETS, with_identity=True)
    wrong_ids = wrong.identity_building_ids
    model = image_model_from_map(pano, true_index, 201.0, OFFSETS, with_identity=True)
    model = ImageModel(
        model.offsets_deg,
        model.facade_present,
        model.orientation_deg,
        wrong_ids,
        wrong.identity_prob,
        bin_deg=model.bin_deg,
    )
    yaw = _yaw_index(201.0)

    def at_truth(options: LikelihoodOptions) -> float:
        return float(pose_likelihood(pano, model, YAWS, options)[true_index, yaw])

    geometry = pose_likelihood(pano, model, YAWS, LikelihoodOptions(use_identity=False))
    np.testing.assert_array_equal(pose_likelihood(pano, model, YAWS, LikelihoodOptions(identity_trust=0.0)), geometry)
    np.testing.assert_array_equal(
        pose_likelihood(pano, model, YAWS, LikelihoodOptions(identity_trust=1.0)),
        pose_likelihood(pano, model, YAWS, LikelihoodOptions()),
    )
    assert at_truth(LikelihoodOptions()) == pytest.approx(0.0, abs=1e-6)  # trusted, wrong identities rule it out
    geometry_at_truth = at_truth(LikelihoodOptions(use_identity=False))
    assert geometry_at_truth > 0.9
    assert at_truth(LikelihoodOptions(identity_trust=0.3)) == pytest.approx(0.7 * geometry_at_truth, rel=1e-5)


def test_posterior_heatmap_and_ranking() -> None:
    city = street_canyon()
    grid, pano, true_index, model = _setup(city, (0.0, 0.0), 60.0, (0.0, -10.0), 0.0)
    post = pose_posterior(pose_likelihood(pano, model, YAWS))
    assert post.sum() == pytest.approx(1.0)
    heat = grid.to_image(position_heatmap(post))
    assert heat.shape == grid.shape and heat[~grid.valid].sum() == 0
    ranked = top_poses(pano.positions, post, YAWS, n=5, min_separation_m=15.0)
    assert len(ranked) == 5 and [r.rank for r in ranked] == [1, 2, 3, 4, 5]
    probs = [r.probability for r in ranked]
    assert probs == sorted(probs, reverse=True)
    xy = np.array([[r.x_m, r.y_m] for r in ranked])
    gaps = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    assert gaps[np.triu_indices(5, 1)].min() >= 15.0


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.booleans(), st.sampled_from(["weighted", "paper"]), st.floats(5.0, 200.0))
def test_likelihood_in_unit_interval(seed: int, identity: bool, normalization: str, sigma: float) -> None:
    rng = np.random.default_rng(seed)
    city = street_canyon()
    pano = _CANYON_PANO
    k = len(OFFSETS)
    present = rng.choice([0.0, 1.0, rng.uniform()], size=k) * (rng.uniform(size=k) < 0.7)
    ids = np.arange(len(city.buildings)) if identity else None
    prob = rng.dirichlet(np.ones(len(city.buildings) + 1), size=k)[:, :-1] if identity else None
    model = ImageModel(OFFSETS, present, rng.uniform(-90, 90, k), ids, prob)
    lik = pose_likelihood(
        pano, model, YAWS[::7], LikelihoodOptions(sigma_m=sigma, normalization=normalization, unknown_weight=0.3)
    )
    assert np.all(np.isfinite(lik)) and lik.min() >= 0.0 and lik.max() <= 1.0 + 1e-6


_CANYON_PANO = cast_panoramas(street_canyon(), grid_around(street_canyon(), (0.0, 0.0), 40.0, 10.0).positions)


def test_skyline_term_tells_distances_apart_where_the_base_is_hidden() -> None:
    from geoloc.localize.likelihood import known_building_heights

    city = square_building()  # 15 m tall, height tagged
    true_xy, near_xy = (0.0, -30.0), (0.0, -22.0)
    pano = cast_panoramas(city, np.array([true_xy, near_xy]))
    model = image_model_from_map(pano, 0, 0.0, OFFSETS, with_identity=False, with_distance=True)
    # The image sees the roof line against the sky but not the base: tan(elevation) = rise / distance.
    top = (15.0 - 1.6) / model.distance_m
    seen = ImageModel(model.offsets_deg, model.facade_present, model.orientation_deg, top_tan_elevation=top)
    heights = known_building_heights(city)
    assert heights.tolist() == [15.0]
    with_sky = pose_likelihood(pano, seen, np.array([0.0]), building_height_m=heights)[:, 0]
    without = pose_likelihood(pano, seen, np.array([0.0]))[:, 0]
    assert with_sky[0] == pytest.approx(1.0, abs=1e-5)
    # 8 m nearer, the roof line would stand much higher than seen. (Seen higher than the map says is
    # penalised less: a taller building behind may show above the one in front.)
    assert with_sky[1] < 0.1 * without[1]
    # A map with only default heights gives no height evidence, so the term stays silent.
    untagged = city_map_from_footprints([np.array([[-10, -10], [10, -10], [10, 10], [-10, 10]], float)])
    assert np.isnan(known_building_heights(untagged)).all()
