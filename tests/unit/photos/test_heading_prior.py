"""The compass as a heading prior: mean in local bearing, sigma with a floor, a floor for a wrong magnetometer."""

from __future__ import annotations

import numpy as np
import pytest

from geoloc.core.geo import LocalFrame
from geoloc.photos.capture import CompassReading
from geoloc.photos.heading_prior import (
    DEFAULT_SIGMA_DEG,
    OUTLIER_PROBABILITY,
    SIGMA_FLOOR_DEG,
    HeadingPrior,
    compass_heading_prior,
)

FRAME = LocalFrame(55.7, 13.19)


def heading_prior_from_compass(
    reading: CompassReading, frame: LocalFrame, east_m: float = 0.0, north_m: float = 0.0
) -> HeadingPrior:
    """The robust prior of a compass reading at a local point (m) of ``frame``."""
    return compass_heading_prior(reading.heading_deg, reading.accuracy_deg, frame, east_m, north_m)


def test_sigma_from_accuracy_with_a_floor() -> None:
    def sigma(accuracy: float | None) -> float:
        return heading_prior_from_compass(CompassReading(10.0, accuracy, "mapillary", "true"), FRAME).sigma_deg

    assert sigma(35.0) == 35.0
    assert sigma(3.0) == SIGMA_FLOOR_DEG
    assert sigma(None) == DEFAULT_SIGMA_DEG


def test_mean_is_the_local_bearing() -> None:
    reading = CompassReading(350.0, 20.0, "exif", "true")
    assert heading_prior_from_compass(reading, FRAME).mean_bearing_deg == pytest.approx(350.0, abs=1e-6)
    east = 20_000.0  # 20 km east of the origin the grid north turns (meridian convergence)
    prior = heading_prior_from_compass(reading, FRAME, east, 0.0)
    assert prior.mean_bearing_deg == pytest.approx(float(FRAME.heading_to_bearing(350.0, east, 0.0)))
    assert abs(prior.mean_bearing_deg - 350.0) > 0.1


def test_weights_peak_at_one_and_never_drop_below_the_outlier_floor() -> None:
    prior = heading_prior_from_compass(CompassReading(355.0, 20.0, "mapillary", "true"), FRAME)
    yaws = np.arange(0.0, 360.0, 0.5)
    weights = prior.weights(yaws)
    assert weights.max() == pytest.approx(1.0, abs=1e-3)
    assert yaws[np.argmax(weights)] == pytest.approx(prior.mean_bearing_deg, abs=0.5)
    assert weights.min() >= OUTLIER_PROBABILITY
    opposite = float(prior.weights(prior.mean_bearing_deg + 180.0))
    assert opposite == pytest.approx(OUTLIER_PROBABILITY, abs=1e-6)  # a wildly wrong compass is survivable
    assert float(prior.weights(prior.mean_bearing_deg + 10.0)) == pytest.approx(
        float(prior.weights(prior.mean_bearing_deg - 10.0))
    )
