"""The heading prior in labelling and grid localisation: a stated heading as before, the compass robust.

Scenes from :mod:`tests.scenes` (rendered image models, so the map's answer is known exactly): the twin
buildings' concave corner is seen from one heading only (240 deg), the street canyon looks the same east and
west.
"""

from __future__ import annotations

import numpy as np
import pytest

from geoloc.localize.grid import GridOptions, localize
from geoloc.localize.labeling import (
    HEADING_PRIOR_SIGMA_DEG,
    LabelOptions,
    ReferenceLabel,
    heading_prior,
    label_reference,
    resolve_heading_prior,
    stated_heading_prior,
)
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.photos.heading_prior import HeadingPrior
from tests.scenes import street_canyon, twin_buildings
from tests.unit.localize.test_labeling_localize import INTRINSICS, _clean_model

CORNER_XY, CORNER_YAW_DEG = (-70.0, 20.0), 240.0
CORNER_GPS = (-67.0, 22.0)
CORNER_OPTIONS = LabelOptions(cell_m=2.0, half_size_m=4.0)


def _wrapped(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def _label_corner(prior: HeadingPrior | None) -> ReferenceLabel:
    city = twin_buildings()
    model, truth = _clean_model(city, CORNER_XY, CORNER_YAW_DEG)
    mask = np.zeros((480, 640), dtype=bool)
    mask[100:300, truth >= 0] = True
    return label_reference(city, model, mask, INTRINSICS, CORNER_GPS, heading_prior=prior, options=CORNER_OPTIONS)


def _yaw_mass_near(label: ReferenceLabel, prior: HeadingPrior | None, yaw_deg: float, within_deg: float) -> float:
    """Share of the labelling's grid weight (likelihood ** sharpness x prior) within ``within_deg`` of a yaw."""
    weights = np.power(label.likelihood.astype(float), CORNER_OPTIONS.sharpness)
    if prior is not None:
        weights = weights * prior.weights(label.yaws_deg)[None, :]
    per_yaw = weights.sum(axis=0) / weights.sum()
    near = np.abs((label.yaws_deg - yaw_deg + 180.0) % 360.0 - 180.0) <= within_deg
    return float(per_yaw[near].sum())


def test_a_stated_heading_weights_bit_identically_to_the_old_gaussian() -> None:
    yaws = np.linspace(0.0, 360.0, 121)[:-1]
    for prior_yaw in (0.0, 37.25, 181.0, 359.9):
        stated = stated_heading_prior(prior_yaw)
        assert stated.sigma_deg == HEADING_PRIOR_SIGMA_DEG and stated.outlier_probability == 0.0
        assert np.array_equal(stated.weights(yaws), heading_prior(yaws, prior_yaw))
        assert float(stated.weights(123.456)) == float(heading_prior(123.456, prior_yaw))


def test_prior_yaw_and_its_stated_prior_give_identical_labels_and_grids() -> None:
    city = street_canyon()
    model, _ = _clean_model(city, (0.0, -2.5), 90.0)
    mask = np.ones((480, 640), dtype=bool)
    options = LabelOptions(cell_m=5.0, half_size_m=0.0)
    old = label_reference(city, model, mask, INTRINSICS, (0.0, -2.5), prior_yaw_deg=270.0, options=options)
    new = label_reference(
        city, model, mask, INTRINSICS, (0.0, -2.5), heading_prior=stated_heading_prior(270.0), options=options
    )
    assert (old.x_m, old.y_m, old.yaw_deg, old.mode_scores) == (new.x_m, new.y_m, new.yaw_deg, new.mode_scores)
    assert np.array_equal(old.marginalized.column_prob, new.marginalized.column_prob)

    twins = twin_buildings()
    corner, _ = _clean_model(twins, CORNER_XY, CORNER_YAW_DEG, with_identity=True)
    likelihood = MapLikelihood(twins, corner)
    grid_old = localize(likelihood, GridOptions(cell_m=10.0), prior_yaw_deg=200.0, top_n=3)
    grid_new = localize(likelihood, GridOptions(cell_m=10.0), heading_prior=stated_heading_prior(200.0), top_n=3)
    assert np.array_equal(grid_old.posterior, grid_new.posterior)
    assert grid_new.search.heading_prior is True


def test_prior_yaw_and_heading_prior_together_are_refused() -> None:
    with pytest.raises(ValueError, match="not both"):
        resolve_heading_prior(10.0, HeadingPrior(10.0, 20.0))
    assert resolve_heading_prior(None, None) is None


@pytest.mark.parametrize("off_by_deg", [120.0, 150.0, 180.0])
def test_a_wildly_wrong_compass_does_not_move_the_label_off_the_maps_answer(off_by_deg: float) -> None:
    unprompted = _label_corner(None)
    assert abs(_wrapped(unprompted.yaw_deg - CORNER_YAW_DEG)) <= 3.0
    wrong = (CORNER_YAW_DEG + off_by_deg) % 360.0
    robust = _label_corner(HeadingPrior(wrong, 20.0, 0.2))  # a phone's stated 20 deg, the outlier floor
    assert abs(_wrapped(robust.yaw_deg - unprompted.yaw_deg)) <= 1.0
    # The same wrong heading as a plain Gaussian (no outlier floor) drags the label away from the corner.
    plain = _label_corner(HeadingPrior(wrong, 20.0, 0.0))
    assert abs(_wrapped(plain.yaw_deg - CORNER_YAW_DEG)) > 30.0


def test_a_right_compass_narrows_the_heading() -> None:
    unprompted = _label_corner(None)
    right = HeadingPrior(CORNER_YAW_DEG + 10.0, 20.0, 0.2)
    narrowed = _label_corner(right)
    assert abs(_wrapped(narrowed.yaw_deg - CORNER_YAW_DEG)) <= 3.0
    before = _yaw_mass_near(unprompted, None, CORNER_YAW_DEG, 15.0)
    after = _yaw_mass_near(narrowed, right, CORNER_YAW_DEG, 15.0)
    assert after > before + 0.05
    # The map alone used to leave a distinct runner-up here (26 deg off and 10 m away, 0.15 of the best, with the
    # vanishing points at +-15 deg) that the compass ruled out; at +-30 deg (VP_TOLERANCE_DEG) the vanishing points
    # bring it onto the corner's pose already. The compass must leave no distinct runner-up either.
    assert narrowed.alternative is None
    assert narrowed.mode_margin >= unprompted.mode_margin
