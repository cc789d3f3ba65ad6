"""A photo's compass as the method's heading prior: a wrapped Gaussian with a uniform outlier floor.

A phone's magnetometer is often wildly wrong (near steel, cars, or uncalibrated): on the Lund walk
(`shared/data/lund`) the first 20 of 29 Mapillary ``TrueHeading`` values point 110-180 degrees away from the
direction of the walk at a stated accuracy of 20 degrees, and on the Berlin photos the readings are
20-28 degrees from the reconstruction's camera directions at a stated 10. So the prior is

    p(yaw) = (1 - eps) * exp(-0.5 * (d / sigma)^2) + eps,   d = wrapped(yaw - mean) in degrees,

scaled to peak at 1 like :func:`geoloc.localize.labeling.heading_prior` (the prior multiplies the
likelihood's weights, so only ratios matter): with eps = :data:`OUTLIER_PROBABILITY` = 0.2 a pose
opposite to the compass keeps a fifth of the weight of one along it, so the image can overrule a wrong
compass. sigma = max(accuracy, :data:`SIGMA_FLOOR_DEG`) (the stated accuracies are optimistic), or
:data:`DEFAULT_SIGMA_DEG` when no accuracy is stated (EXIF ``GPSImgDirection`` carries none).

Used by reference labelling and the query stage (``heading_prior=`` of
:func:`geoloc.localize.reference.label_reference_photo` and :func:`geoloc.localize.query.geolocate`) when the
service takes the heading from the photo's compass; a heading the user states is today's plain Gaussian
(:func:`geoloc.localize.labeling.stated_heading_prior`, eps = 0), so answers with a stated heading are unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoloc.core.geo import LocalFrame
from geoloc.photos.capture import CompassReading

SIGMA_FLOOR_DEG = 15.0
"""Smallest prior sigma (deg), whatever accuracy the phone states."""

DEFAULT_SIGMA_DEG = 30.0
"""Prior sigma (deg) of a reading without a stated accuracy."""

OUTLIER_PROBABILITY = 0.2
"""The prior's uniform floor: the chance that the magnetometer is wildly wrong."""


@dataclass(frozen=True)
class HeadingPrior:
    """A heading prior in a map's local frame.

    mean_bearing_deg: local bearing (deg clockwise from grid north, [0, 360)). sigma_deg: the Gaussian's
    sigma (deg). outlier_probability: the uniform floor eps in [0, 1).
    """

    mean_bearing_deg: float
    sigma_deg: float
    outlier_probability: float = OUTLIER_PROBABILITY

    def weights(self, yaws_deg: np.ndarray | float) -> np.ndarray:
        """Prior weights of local-bearing yaws (deg), peak 1 at the mean, ``outlier_probability`` far away."""
        delta = (np.asarray(yaws_deg, dtype=float) - self.mean_bearing_deg + 180.0) % 360.0 - 180.0
        eps = self.outlier_probability
        out: np.ndarray = (1.0 - eps) * np.exp(-0.5 * (delta / self.sigma_deg) ** 2) + eps
        return out


def compass_accuracy_deg(reading: CompassReading) -> float:
    """A compass reading's accuracy as stored and weighed (deg): its own, or :data:`DEFAULT_SIGMA_DEG` unstated.

    The service stores this with the heading; a stored heading without an accuracy is one the uploader stated
    (:func:`geoloc.localize.reference.heading_prior_at`).
    """
    return DEFAULT_SIGMA_DEG if reading.accuracy_deg is None else reading.accuracy_deg


def compass_heading_prior(
    heading_deg: float,
    accuracy_deg: float | None,
    frame: LocalFrame,
    east_m: float = 0.0,
    north_m: float = 0.0,
    *,
    sigma_floor_deg: float = SIGMA_FLOOR_DEG,
    default_sigma_deg: float = DEFAULT_SIGMA_DEG,
    outlier_probability: float = OUTLIER_PROBABILITY,
) -> HeadingPrior:
    """The robust prior of a compass heading (deg from true north) with its accuracy (deg, None: unstated).

    The point (``east_m``, ``north_m``, local m of ``frame``) gives the meridian convergence. sigma is the
    accuracy floored at ``sigma_floor_deg``, or ``default_sigma_deg`` without one; eps is ``outlier_probability``.
    """
    sigma = default_sigma_deg if accuracy_deg is None else max(float(accuracy_deg), sigma_floor_deg)
    bearing = float(frame.heading_to_bearing(heading_deg, east_m, north_m))
    return HeadingPrior(bearing % 360.0, float(sigma), float(outlier_probability))
