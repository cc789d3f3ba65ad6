import dataclasses
import inspect

import numpy as np
import pytest

from geoloc.core.camera import Intrinsics
from geoloc.localize.grid import GridOptions, PositionPrior, localize
from geoloc.localize.label_covariance import (
    GPS_DISAGREEMENT_WEIGHT,
    STATED_SIGMA_SCALE,
    stated_position_covariance,
)
from geoloc.localize.labeling import LabelOptions, column_building_ids, label_reference, says_little
from geoloc.localize.likelihood import LikelihoodOptions, image_model_from_map
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.posterior import sharpened_likelihood
from geoloc.localize.reference import LabelCues, label_from_cues
from geoloc.localize.reference import LabelOptions as ReferenceLabelOptions
from geoloc.localize.refinement import RefineOptions, refine_pose, vanishing_point_yaw
from geoloc.localize.sequence.frames import MAP_SPREAD_HALF_SIZE_M, map_position_covariance
from geoloc.maps.raycast import cast_panoramas
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.vision.features import Features
from geoloc.vision.image_model import ImageModel, bin_offsets_deg
from tests.scenes import street_canyon, twin_buildings

INTRINSICS = Intrinsics.from_hfov(640, 480, 60.0)
OFFSETS = bin_offsets_deg(INTRINSICS)


def _clean_model(city, xy, yaw, with_identity=False, with_distance=False) -> tuple[ImageModel, np.ndarray]:
    pano = cast_panoramas(city, np.array([xy], dtype=float))
    model = image_model_from_map(pano, 0, yaw, OFFSETS, with_identity=with_identity, with_distance=with_distance)
    truth = column_building_ids(pano, np.array([yaw]), INTRINSICS, OFFSETS, 0.5)[0, 0]
    return model, truth


def test_reference_labelling_recovers_heading_position_and_identities() -> None:
    city = street_canyon()
    true_xy, true_yaw = (0.0, -10.0), 48.0
    model, truth = _clean_model(city, true_xy, true_yaw)
    mask = np.zeros((480, 640), dtype=bool)
    mask[100:300, truth >= 0] = True
    # GPS off by 7 m: the 3 x 3 grid around it contains the true position.
    options = LabelOptions(cell_m=3.0, half_size_m=6.0)
    label = label_reference(city, model, mask, INTRINSICS, (6.0, -6.0), options=options)
    assert abs((label.yaw_deg - true_yaw + 180) % 360 - 180) <= 3.0
    # The position is only as good as the view constrains it (no depth in the image model): it stays
    # within the sampled grid and the likelihood there is near perfect.
    assert label.best_likelihood > 0.95
    for identity in (label.greedy, label.marginalized):
        predicted = identity.pixel_ids()
        truth_pixels = np.where(mask, truth[None, :], -1)
        assert np.mean(predicted[mask] == truth_pixels[mask]) > 0.9
    # Marginal probabilities are probabilities.
    prob = label.marginalized.column_prob
    assert prob.min() >= 0 and prob.sum(axis=1).max() <= 1 + 1e-5


def test_a_label_states_more_doubt_the_further_it_lies_from_its_own_gps_fix() -> None:
    """The stated covariance: the posterior's scaled, plus the squared disagreement with the fix (dev-split fit)."""
    posterior = np.array([[1.0, 0.5], [0.5, 2.0]])
    on_fix = stated_position_covariance(posterior, (3.0, 4.0), (3.0, 4.0))
    np.testing.assert_allclose(on_fix, STATED_SIGMA_SCALE**2 * posterior)
    off_fix = stated_position_covariance(posterior, (3.0, 4.0), (0.0, 0.0))  # 5 m from its fix
    np.testing.assert_allclose(off_fix - on_fix, GPS_DISAGREEMENT_WEIGHT * 25.0 * np.eye(2))
    # The labelling stage states that of its refined pose and the GPS it was given; the posterior stays unscaled.
    city = street_canyon()
    model, truth = _clean_model(city, (0.0, -10.0), 48.0)
    mask = np.zeros((480, 640), dtype=bool)
    mask[100:300, truth >= 0] = True
    gps, options = (6.0, -6.0), LabelOptions(cell_m=3.0, half_size_m=6.0)
    cues = LabelCues(Features.empty((480, 640)), model, mask, np.eye(3))
    stated = label_from_cues(city, INTRINSICS, cues, {}, gps, options=options).label
    posterior = label_reference(city, model, mask, INTRINSICS, gps, options=options)
    assert (stated.x_m, stated.y_m) == (posterior.x_m, posterior.y_m)
    assert (stated.x_m - gps[0]) ** 2 + (stated.y_m - gps[1]) ** 2 > 1.0
    expected = stated_position_covariance(posterior.position_covariance, (posterior.x_m, posterior.y_m), gps)
    np.testing.assert_allclose(stated.position_covariance, expected)


def test_heading_prior_picks_among_ambiguous_headings() -> None:
    city = street_canyon()
    model, _ = _clean_model(city, (0.0, -2.5), 90.0)  # looking at the east wall head-on
    mask = np.ones((480, 640), dtype=bool)
    # Without a prior looking east or west at the same distance is ambiguous in a symmetric canyon.
    label = label_reference(
        city,
        model,
        mask,
        INTRINSICS,
        (0.0, -2.5),
        prior_yaw_deg=270.0,
        options=LabelOptions(cell_m=5.0, half_size_m=0.0),
    )
    assert abs((label.yaw_deg - 270.0 + 180) % 360 - 180) <= 3.0


def test_localize_with_identity_finds_the_right_twin() -> None:
    city = twin_buildings()
    # Looking into the West building's concave corner; the twin pose is 200 m east.
    true_xy, true_yaw = (-70.0, 20.0), 240.0
    model, _ = _clean_model(city, true_xy, true_yaw, with_identity=True)
    found = localize(MapLikelihood(city, model), GridOptions(cell_m=10.0), top_n=3)
    assert found.search.region == "identified_buildings" and found.search.buildings == [0]
    best = found.poses[0]
    assert (best.x_m, best.y_m) == true_xy and abs(best.yaw_deg - true_yaw) < 1e-6
    assert all(p.x_m < 0 for p in found.poses)
    assert found.heatmap.shape == found.grid.shape
    assert found.heatmap.sum() == pytest.approx(1.0)
    # Geometry only, searched around both buildings: the twin pose ranks next to the true one.
    geometry = MapLikelihood(city, model, LikelihoodOptions(use_identity=False))
    both = localize(geometry, GridOptions(min_separation_m=20.0), candidate_buildings=[0, 1], top_n=2)
    assert sorted(p.x_m for p in both.poses) == [-70.0, 130.0]


def test_localize_uses_position_prior_and_refinement_reaches_the_true_pose() -> None:
    city = twin_buildings()
    true_xy, true_yaw = (131.3, 21.7), 241.4  # off the 10 m grid and off the 3 deg yaws
    model, _ = _clean_model(city, true_xy, true_yaw, with_distance=True)
    prior = PositionPrior.from_radius(125.0, 15.0, 30.0)
    geometry = MapLikelihood(city, model, LikelihoodOptions(use_identity=False))
    found = localize(geometry, position_prior=prior)
    assert found.search.region == "position_prior" and found.search.position_prior
    best = found.poses[0]
    assert np.hypot(best.x_m - true_xy[0], best.y_m - true_xy[1]) < 7.5 and abs(best.yaw_deg - true_yaw) <= 3.0
    refined = refine_pose(
        geometry, best.x_m, best.y_m, best.yaw_deg, options=RefineOptions(half_size_m=6.0, cell_m=0.5)
    )
    # The perfect model's facade orientations fix the yaw, its distances and extents the position.
    assert abs((refined.yaw_deg - true_yaw + 180) % 360 - 180) < 0.3
    assert np.hypot(refined.x_m - true_xy[0], refined.y_m - true_xy[1]) < 1.0
    assert refined.vp_bins > 20 and refined.likelihood > 0.9


def test_a_prior_whose_region_lies_inside_a_building_grows_to_the_street() -> None:
    city = street_canyon()
    true_xy, true_yaw = (0.0, -2.5), 90.0
    model, _ = _clean_model(city, true_xy, true_yaw, with_distance=True)
    geometry = MapLikelihood(city, model, LikelihoodOptions(use_identity=False))
    inside = PositionPrior.from_radius(25.0, 0.0, 10.0)  # a fix 15 m into the east block, stated to 5 m
    assert inside.region(3.0).within(city.buildings[3].polygon.buffer(0.1))  # no open ground within 3 sigma
    found = localize(geometry, position_prior=inside)
    assert found.search.positions > 0 and found.search.region == "position_prior"
    best = found.poses[0]
    assert -10.0 <= best.x_m <= 10.0  # in the street, the nearest open ground
    assert np.hypot(best.x_m - 25.0, best.y_m) < 25.0 + 5.0  # where the region grew to, near the fix


def test_vanishing_point_yaw_is_exact_given_the_facade_seen() -> None:
    city = street_canyon()
    true_yaw = 77.3  # looking at the east wall 12.7 deg from head-on
    model, _ = _clean_model(city, (0.0, -2.5), true_yaw)
    for start in (70.0, 84.0):  # a grid yaw off by up to 7 deg
        yaw, support = vanishing_point_yaw(city, model, 0.0, -2.5, start)
        assert support > 20 and abs(yaw - true_yaw) < 0.3
    # Nothing in view that agrees: the yaw is left alone and no support is reported.
    empty = ImageModel(OFFSETS, np.zeros(len(OFFSETS)), np.zeros(len(OFFSETS)))
    assert vanishing_point_yaw(city, empty, 0.0, -2.5, 70.0) == (70.0, 0)


def test_a_photo_the_map_says_nothing_of_is_placed_by_its_gps_and_compass() -> None:
    """No facade evidence (a wall filling the frame, open ground): every pose's weight is zero, so the priors decide.

    Before, the first pose of the table of zeros won: the grid's corner, heading north, refined to another corner.
    """
    city = street_canyon()
    empty = ImageModel(OFFSETS, np.zeros(len(OFFSETS)), np.zeros(len(OFFSETS)))
    table = MapLikelihood(city, empty).of_poses(np.array([[0.0, -2.5], [0.0, 3.0]]), np.array([0.0, 123.0]))
    assert sharpened_likelihood(table) is None  # what the map says of this photo: nothing
    gps = (0.0, -2.5)
    mask = np.zeros((480, 640), dtype=bool)
    label = label_reference(city, empty, mask, INTRINSICS, gps, heading_prior=HeadingPrior(123.0, 15.0))
    assert abs((label.yaw_deg - 123.0 + 180) % 360 - 180) <= 3.0  # the grid's nearest yaw to the compass
    assert np.hypot(label.x_m - gps[0], label.y_m - gps[1]) <= LabelOptions().cell_m
    refined = refine_pose(MapLikelihood(city, empty), 1.0, -2.0, 123.0, prior_xy=gps, prior_sigma_m=8.0)
    assert refined.yaw_deg == 123.0 and np.hypot(refined.x_m - gps[0], refined.y_m - gps[1]) <= 1.0
    assert refined.vp_bins == 0


def test_position_prior_radius_is_two_sigma() -> None:
    prior = PositionPrior.from_radius(0.0, 0.0, 50.0)
    assert prior.sigma_m == 25.0 and prior.radius_m == 50.0
    weights = prior.weights(np.array([[0.0, 0.0], [25.0, 0.0]]))
    assert weights[0] == 1.0 and weights[1] == pytest.approx(np.exp(-0.5))


def test_label_options_are_label_reference_defaults() -> None:
    """``label_reference`` takes its tuning as one ``LabelOptions`` (the reference stage's), by default the defaults."""
    keywords = {
        name: parameter.default
        for name, parameter in inspect.signature(label_reference).parameters.items()
        if parameter.kind is inspect.Parameter.KEYWORD_ONLY
    }
    assert keywords == {"prior_yaw_deg": None, "heading_prior": None, "options": LabelOptions(), "known_pose": None}
    assert ReferenceLabelOptions is LabelOptions
    assert dataclasses.asdict(LabelOptions())["gps_sigma_m"] == 8.0 and LabelOptions().n_modes == 3


def test_a_photo_showing_next_to_no_facade_is_labelled_by_its_gps_and_not_weighed_in_its_walk() -> None:
    """Mean facade evidence under OPEN_GROUND_EVIDENCE (open ground, far buildings): the map is not weighed.

    The same view with full evidence moves the label from its GPS toward the truth; with a tenth of it (a few weak
    columns, as on open ground) the label stays at its GPS, and the walk's graph gets no map spread from it.
    """
    city = street_canyon()
    model, _ = _clean_model(city, (0.0, -10.0), 48.0)
    weak = dataclasses.replace(model, facade_present=model.facade_present * 0.1)
    assert says_little(weak) and not says_little(model)
    mask = np.zeros((480, 640), dtype=bool)
    gps = (6.0, -6.0)
    options = LabelOptions(cell_m=3.0, half_size_m=6.0)
    strong = label_reference(
        city, model, mask, INTRINSICS, gps, heading_prior=HeadingPrior(60.0, 15.0), options=options
    )
    assert np.hypot(strong.x_m - gps[0], strong.y_m - gps[1]) > 2.0  # the map moves a label it sees
    label = label_reference(city, weak, mask, INTRINSICS, gps, heading_prior=HeadingPrior(60.0, 15.0), options=options)
    assert np.hypot(label.x_m - gps[0], label.y_m - gps[1]) <= options.cell_m / 2
    spread = map_position_covariance(city, weak, label.x_m, label.y_m, label.yaw_deg)
    assert np.allclose(spread, np.eye(2) * MAP_SPREAD_HALF_SIZE_M**2)
