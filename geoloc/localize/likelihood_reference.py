"""The specification of the likelihood kernel: :func:`pose_likelihood_numpy`, the same formula in plain numpy.

Not used by the runtime: the tests check :func:`geoloc.localize.likelihood.pose_likelihood` (the compiled
kernel) against it (equal to float32 rounding) and ``benchmarks/bench_core.py`` times the two side by side.
"""

from __future__ import annotations

import numpy as np

from geoloc.core.camera import wrap_orientation_deg
from geoloc.localize.likelihood import DISTANCE_NEAR_SLACK, LikelihoodOptions, _terms
from geoloc.maps.raycast import Panoramas
from geoloc.vision.image_model import ImageModel


def pose_likelihood_numpy(
    panoramas: Panoramas,
    image_model: ImageModel,
    yaws_deg: np.ndarray | None = None,
    options: LikelihoodOptions = LikelihoodOptions(),
    building_height_m: np.ndarray | None = None,
    chunk_elements: int = 8_000_000,
) -> np.ndarray:
    """:func:`geoloc.localize.likelihood.pose_likelihood` in plain vectorised numpy: (P, Y) arrays of every term.

    In chunks of positions (``chunk_elements`` samples at a time). The specification of the compiled kernel
    (same arguments, results equal to float32 rounding); the tests and the core benchmark compare the two.
    """
    terms = _terms(panoramas, image_model, yaws_deg, options, building_height_m)
    distance_sigma_log, height_sigma_log = options.distance_sigma_log, options.height_sigma_log
    yaws, window, present, theta_hat = terms.yaws, terms.window, terms.present, terms.theta_hat
    identity_lut, log_distance_hat = terms.identity_lut, terms.log_distance_hat
    log_rise, log_top_hat = terms.log_rise, terms.log_top_hat
    n_pos = len(panoramas)
    out = np.zeros((n_pos, len(yaws)), dtype=np.float32)
    per_position = max(1, window.size)
    step = max(1, chunk_elements // per_position)
    inv_two_sigma2 = 1.0 / (2.0 * options.sigma_m**2)
    # The relative orientation theta_k = normal bearing - yaw; the yaw term is per row of the window.
    yaw_col = yaws.astype(np.float32)[None, :, None]
    for start in range(0, n_pos, step):
        sl = slice(start, min(start + step, n_pos))
        dist = panoramas.distance_m[sl][:, window]  # (p, Y, K)
        hit = np.isfinite(dist)
        weight = np.where(hit, np.exp(-np.square(np.where(hit, dist, 0.0)) * inv_two_sigma2), 0.0)
        theta = wrap_orientation_deg(panoramas.normal_bearing_deg[sl][:, window] - yaw_col)
        agree = np.abs(np.cos(np.radians(theta - theta_hat[None, None, :])))
        score = weight * np.where(hit, agree, 0.0) * present[None, None, :]
        if log_distance_hat is not None:
            z = (
                np.log(np.where(hit, np.maximum(dist, 0.1), 1.0)) - log_distance_hat[None, None, :]
            ) / distance_sigma_log
            # A base line seen too high (its bottom rows taken for road, a shadow, a kerb) makes the image's
            # distance too long; one seen too low is rare. So a map facade nearer than the image says costs less.
            z = np.where(z < 0, DISTANCE_NEAR_SLACK * z, z)
            score = score * np.where(np.isfinite(z), np.exp(-0.5 * np.square(np.nan_to_num(z))), 1.0)
        if log_rise is not None and log_top_hat is not None:
            building_hit = panoramas.building_id[sl][:, window]
            # ln(implied rise) - ln(map rise): > 0 where the image's top is higher than the map's building.
            z = (
                np.log(np.where(hit, np.maximum(dist, 0.1), 1.0))
                + log_top_hat[None, None, :]
                - log_rise[building_hit + 1]
            ) / height_sigma_log
            z = np.where(z > 0, 0.25 * z, z)  # a taller building behind may show above: penalise less
            score = score * np.where(np.isfinite(z), np.exp(-0.5 * np.square(np.nan_to_num(z))), 1.0)
        if identity_lut is not None:
            building = panoramas.building_id[sl][:, window]
            k_index = np.broadcast_to(np.arange(len(present))[None, None, :], building.shape)
            score = score * identity_lut[k_index, building + 1]
        s = score.sum(axis=-1)
        if options.normalization == "paper":
            s_max = present.sum() + ((1.0 - present)[None, None, :] * weight).sum(axis=-1)
        else:
            s_max = (weight + present[None, None, :] * ~hit).sum(axis=-1)
        out[sl] = np.where(s_max > 0, s / np.maximum(s_max, 1e-12), 0.0)
    return out
