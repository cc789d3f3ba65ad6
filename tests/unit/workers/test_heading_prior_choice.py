"""How the worker weights a stored heading prior (:func:`geoloc.localize.reference.heading_prior_at`)."""

from __future__ import annotations

import pytest

from geoloc.core.geo import LocalFrame
from geoloc.localize.labeling import HEADING_PRIOR_SIGMA_DEG
from geoloc.localize.reference import heading_prior_at
from geoloc.photos.heading_prior import OUTLIER_PROBABILITY, SIGMA_FLOOR_DEG

FRAME = LocalFrame(55.7, 13.19)


def test_the_worker_weights_a_stated_heading_as_before_and_a_compass_robustly() -> None:
    assert heading_prior_at(FRAME, None, None) is None
    assert heading_prior_at(FRAME, None, 20.0) is None
    stated = heading_prior_at(FRAME, 90.0, None)
    assert stated is not None
    assert (stated.sigma_deg, stated.outlier_probability) == (HEADING_PRIOR_SIGMA_DEG, 0.0)
    assert stated.mean_bearing_deg == float(FRAME.heading_to_bearing(90.0, 0.0, 0.0))
    sharp = heading_prior_at(FRAME, 90.0, 5.0, 100.0, 50.0)
    assert sharp is not None and sharp.sigma_deg == SIGMA_FLOOR_DEG and sharp.outlier_probability == OUTLIER_PROBABILITY
    assert sharp.mean_bearing_deg == pytest.approx(float(FRAME.heading_to_bearing(90.0, 100.0, 50.0)) % 360.0)
    wide = heading_prior_at(FRAME, 90.0, 40.0)
    assert wide is not None and wide.sigma_deg == 40.0
    # Opposite the compass a fifth of the weight stays: the image can overrule a wrong magnetometer.
    assert float(wide.weights(wide.mean_bearing_deg + 180.0)) == pytest.approx(OUTLIER_PROBABILITY, abs=1e-3)
