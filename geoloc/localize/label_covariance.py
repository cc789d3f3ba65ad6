"""What a labelled reference states of its position: its posterior's covariance, calibrated on the accuracy suite.

Local frame of the map, metres; the fit and why it has this form: :data:`GPS_DISAGREEMENT_WEIGHT`.
"""

from __future__ import annotations

import numpy as np

STATED_SIGMA_SCALE = 1.5
GPS_DISAGREEMENT_WEIGHT = 0.2
"""A label's stated position covariance (:func:`stated_position_covariance`): its posterior's, times this scale
squared, plus this weight times the squared distance between the label and its own GPS fix (isotropic).

Fitted on the accuracy suite's dev split (960 references of 24 worlds, docs/measurements/accuracy.md, "A
reference's stated sigma"): the posterior's covariance held the truth within 2 sigma for 0.71 (0.86 if true), and
for 0.60-0.61 in parks and along wide roads, because a label the map places on the wrong stretch of facade is as
sure of itself as a right one. Scaling alone to 0.86 leaves parks at 0.76; the distance from the fix is the one
figure a label has that grows with its chance of being wrong (labels more than 7 m from their fix: 0.60 within
2 sigma against 0.80 for those within 3 m)."""


def stated_position_covariance(
    posterior_covariance: np.ndarray, position_xy: tuple[float, float], gps_xy: tuple[float, float]
) -> np.ndarray:
    """(2, 2) m^2 the covariance a reference states for its pose.

    posterior_covariance: (2, 2) m^2 of the pose's posterior (a label's refinement, or a walk's joint placement);
    position_xy, gps_xy: the pose's position and the photo's own GPS fix (local m). Returns
    :data:`STATED_SIGMA_SCALE` squared times the posterior's plus :data:`GPS_DISAGREEMENT_WEIGHT` times the squared
    distance between the two, on the diagonal.
    """
    disagreement_m2 = float(np.sum((np.asarray(position_xy, dtype=float) - np.asarray(gps_xy, dtype=float)) ** 2))
    covariance = STATED_SIGMA_SCALE**2 * np.asarray(posterior_covariance, dtype=float)
    return covariance + GPS_DISAGREEMENT_WEIGHT * disagreement_m2 * np.eye(2)
