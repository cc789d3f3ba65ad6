"""Continuous pose refinement against the map: sub-degree yaw from vanishing points, sub-metre position search.

The pose likelihood (:mod:`geoloc.localize.likelihood`) is evaluated on grids (metres x 3 deg yaws), which cannot
give metres and degrees. Two refinements start from a grid pose:

- :func:`vanishing_point_yaw`: each image bin with a facade hypothesis measures the facade's orientation
  theta_hat relative to the camera to a fraction of a degree (from its horizontal vanishing point). At a
  candidate position the map says which facade the bin sees, with outward-normal bearing n; the camera
  yaw is then ``n - theta_hat`` (modulo 180, the branch nearest the current yaw). The robust median over
  the bins whose prediction agrees within ``tolerance_deg`` is the new yaw; two passes, since the facade
  a bin sees depends on the yaw.
- :func:`refine_pose`: the likelihood on a fine grid of positions around the pose (``cell_m``, default
  0.5 m) at a few yaws around the vanishing-point yaw, times a Gaussian position prior; the best pose, and
  the posterior's spread as a covariance of the position (the honest "how sure", not a grid cell).

Both take the image model (its per-bin orientations and offsets; :func:`refine_pose` through the photo's
:class:`geoloc.localize.map_likelihood.MapLikelihood`), so references and queries use the same code.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.posterior import DEFAULT_SHARPNESS, sharpened_likelihood
from geoloc.maps import CityMap
from geoloc.maps.raycast import cast_panoramas
from geoloc.vision.image_model import ImageModel

VP_BEARING_STEP_DEG = 0.1
"""Bearing step of the panorama that tells which facade each bin sees during the yaw refinement."""
MIN_VP_BINS = 6
"""Bins that must agree before a vanishing-point yaw replaces the grid yaw."""
VP_TOLERANCE_DEG = 30.0
"""The image bins within this of the current yaw take part in the vanishing-point yaw (every use: a label's, a
query's, a walk's placed frame). 30 deg, not the first 15: poses 5-30 deg off were out of reach at 15, while a
Manhattan facade's other direction is 90 deg away. On the accuracy suite's dev split: references' headings within
2 deg +0.019 [+0.005, +0.033], queries' headings within 5 deg +0.022 [+0.005, +0.040], labels and queries at 30
against 15 (placed frames were already at 30: +0.042 [+0.013, +0.072] against none; docs/measurements/accuracy.md,
"A placed frame's heading from the facades it sees" and "Every vanishing-point yaw at ±30°")."""


@dataclass
class RefinedPose:
    """A pose refined against the map (local frame).

    x_m, y_m, yaw_deg: the pose. likelihood: p(I | pose). posterior: likelihood ** sharpness x prior at it.
    position_covariance: (2, 2) m^2 spread of the fine-grid posterior (at least the cell's own variance).
    vp_bins: bins that supported the vanishing-point yaw (0: the yaw was not refined by vanishing points).
    """

    x_m: float
    y_m: float
    yaw_deg: float
    likelihood: float
    posterior: float
    position_covariance: np.ndarray
    vp_bins: int


def vanishing_point_yaw(
    city_map: CityMap,
    image_model: ImageModel,
    x_m: float,
    y_m: float,
    yaw_deg: float,
    *,
    tolerance_deg: float = VP_TOLERANCE_DEG,
    passes: int = 2,
) -> tuple[float, int]:
    """Yaw (local bearing, deg) from the image's facade orientations and the map's facades seen from (x, y).

    Returns (yaw, supporting bins); the input yaw and 0 when fewer than :data:`MIN_VP_BINS` bins agree.
    """
    present = image_model.facade_present > 0
    if not present.any():
        return yaw_deg % 360.0, 0
    n_bearings = int(round(360.0 / VP_BEARING_STEP_DEG))
    position = np.array([[x_m, y_m]])
    # Only the bearings the bins can read are cast, once: each pass moves the yaw by under tolerance_deg. They are
    # the full 0.1 deg panorama's rays, so the same bits.
    reach_deg = (passes - 1) * tolerance_deg + VP_BEARING_STEP_DEG
    first, last = (
        int(np.floor((yaw_deg + np.min(image_model.offsets_deg) - reach_deg) / VP_BEARING_STEP_DEG)),
        int(np.ceil((yaw_deg + np.max(image_model.offsets_deg) + reach_deg) / VP_BEARING_STEP_DEG)),
    )
    cast = np.zeros(n_bearings, dtype=bool)
    cast[np.arange(first, last + 1) % n_bearings] = True
    panorama = cast_panoramas(
        city_map, position, bearing_step_deg=VP_BEARING_STEP_DEG, bearing_indices=np.flatnonzero(cast)
    )
    yaw = float(yaw_deg)
    support = 0
    for _ in range(passes):
        index = np.round(((yaw + image_model.offsets_deg) % 360.0) / VP_BEARING_STEP_DEG).astype(np.int64) % n_bearings
        if not cast[index].all():  # beyond the reach (it cannot be): cast what is missing too
            cast[index] = True
            panorama = cast_panoramas(
                city_map, position, bearing_step_deg=VP_BEARING_STEP_DEG, bearing_indices=np.flatnonzero(cast)
            )
        normal = panorama.normal_bearing_deg[0, index]
        delta = ((normal - image_model.orientation_deg) - yaw + 90.0) % 180.0 - 90.0
        agree = present & np.isfinite(delta) & (np.abs(delta) < tolerance_deg)
        support = int(agree.sum())
        if support < MIN_VP_BINS:
            return yaw_deg % 360.0, 0
        yaw += float(np.median(delta[agree]))
    return yaw % 360.0, support


def position_spread(positions: np.ndarray, weights: np.ndarray, cell_m: float) -> np.ndarray | None:
    """(2, 2) m^2 spread of (P, 2) grid positions about their mean under (P,) weights, plus a cell's own variance.

    None when nothing has weight.
    """
    total = weights.sum()
    if not total > 0:
        return None
    w = weights / total
    centred = positions - w @ positions
    spread: np.ndarray = (centred * w[:, None]).T @ centred + np.eye(2) * (cell_m**2 / 12.0)
    return spread


@dataclass(frozen=True)
class RefineOptions:
    """The search of :func:`refine_pose`.

    A square of ``half_size_m`` (m) in cells of ``cell_m`` around the pose, these yaw offsets (deg) around its
    yaw, the likelihood sharpened by ``sharpness``, and the yaw fixed by the vanishing points before and after
    (``use_vanishing_points``).
    """

    half_size_m: float = 6.0
    cell_m: float = 1.0
    yaw_offsets_deg: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)
    sharpness: float = DEFAULT_SHARPNESS
    use_vanishing_points: bool = True


def refine_pose(
    likelihood: MapLikelihood,
    x_m: float,
    y_m: float,
    yaw_deg: float,
    *,
    prior_xy: tuple[float, float] | None = None,
    prior_sigma_m: float | None = None,
    prior_weights: Callable[[np.ndarray], np.ndarray] | None = None,
    options: RefineOptions = RefineOptions(),
) -> RefinedPose:
    """Refine a pose: vanishing-point yaw, then the best of a fine grid of positions x yaws around it.

    likelihood: the photo's map likelihood (identity-aware when its options ask for it and its image model
    carries identities). prior_xy, prior_sigma_m: optional Gaussian position prior (e.g. the GPS tag);
    prior_weights: or any position prior, as its weights of (P, 2) positions (e.g. ``PositionPrior.weights``).
    Positions inside buildings are skipped; options: the search (:class:`RefineOptions`).
    """
    half_size_m, cell_m, yaw_offsets_deg = options.half_size_m, options.cell_m, options.yaw_offsets_deg
    sharpness, use_vanishing_points = options.sharpness, options.use_vanishing_points
    city_map, image_model = likelihood.city_map, likelihood.image_model
    yaw, vp_bins = (
        vanishing_point_yaw(city_map, image_model, x_m, y_m, yaw_deg) if use_vanishing_points else (yaw_deg, 0)
    )
    n = int(np.floor(half_size_m / cell_m))
    offsets = np.arange(-n, n + 1) * cell_m
    positions = np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2) + np.array([x_m, y_m])
    positions = positions[~city_map.inside_buildings(positions)]
    if len(positions) == 0:
        positions = np.array([[x_m, y_m]])
    yaws = yaw + np.asarray(yaw_offsets_deg, dtype=float)
    table = likelihood.of_poses(positions, yaws).astype(float)
    sharpened = sharpened_likelihood(table, sharpness)
    weight = sharpened if sharpened is not None else np.ones(table.shape)
    if prior_xy is not None and prior_sigma_m:
        d2 = np.sum((positions - np.asarray(prior_xy, dtype=float)) ** 2, axis=1)
        weight = weight * np.exp(-0.5 * d2 / prior_sigma_m**2)[:, None]
    if prior_weights is not None:
        weight = weight * prior_weights(positions)[:, None]
    best_p, best_y = (int(i) for i in np.unravel_index(int(np.argmax(weight)), weight.shape))
    if sharpened is None:  # the map says nothing: the prior's position, the heading as given
        best_y = int(np.argmin(np.abs(yaws - yaw)))
    best_yaw = float(yaws[best_y])
    if use_vanishing_points:
        # The facades seen from the refined position fix the yaw to a fraction of a degree.
        vp_yaw, support = vanishing_point_yaw(
            city_map, image_model, float(positions[best_p, 0]), float(positions[best_p, 1]), best_yaw
        )
        if support:
            best_yaw, vp_bins = vp_yaw, support
    spread = position_spread(positions, weight.sum(axis=1), cell_m)
    covariance = spread if spread is not None else np.eye(2) * half_size_m**2
    return RefinedPose(
        float(positions[best_p, 0]),
        float(positions[best_p, 1]),
        best_yaw % 360.0,
        float(table[best_p, best_y]),
        float(weight[best_p, best_y]),
        covariance,
        vp_bins,
    )
