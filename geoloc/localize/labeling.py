"""Reference labelling: a geo-tagged photo's pose and its building pixels' identities, from the map.

The heading (and corrected position) of the photo, and a building identity for each of its building
pixels (paper: "Assigning Building Identity to Pixels").

Poses are sampled around the GPS tag (paper: 3 x 3 positions 10 m apart x 120 yaws; here the grid
spacing and half-size are parameters), each is scored with the pose likelihood, and:

- greedy: the best pose's projection gives every building pixel the building the map shows in its
  column (probability 1);
- marginalised: p(b | column) = sum_g p(I|g) 1(b_column(g) = b) / sum_g p(I|g), uniform prior over the
  sampled poses (or a heading prior when the photo carries one). Mass of poses that show no building in
  a column stays "unknown".

Identities are per column, so a building pixel takes its column's building (as in the paper).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.localize.identity import IdentityMap
from geoloc.localize.likelihood import DEFAULT_SIGMA_M, LikelihoodOptions, default_yaws_deg
from geoloc.localize.map_likelihood import MapLikelihood
from geoloc.localize.posterior import DEFAULT_SHARPNESS, grid_around, sharpened_likelihood
from geoloc.localize.refinement import RefinedPose, RefineOptions, refine_pose
from geoloc.maps import CityMap
from geoloc.maps.raycast import Panoramas, panorama_window
from geoloc.photos.heading_prior import HeadingPrior
from geoloc.vision.image_model import ImageModel, column_bins

DEFAULT_REFERENCE_CELL_M = 2.0
DEFAULT_REFERENCE_HALF_SIZE_M = 10.0
DEFAULT_GPS_SIGMA_M = 8.0
"""Gaussian prior on the position around the GPS tag (phone GPS error); None gives the paper's uniform prior.

Measured on 40 references of a simulated Helsinki world (5 m GPS noise, ground-truth labels), heading
error median / within 5 deg / flipped by ~180 deg, and marginalised identity accuracy:
paper's 3 x 3 at 10 m, uniform prior, plain weights: 11.3 deg / 30 % / 30 %, 0.55;
11 x 11 at 2 m, uniform prior, plain weights: 1.2 deg / 72 % / 17 %, 0.57;
11 x 11 at 2 m, this prior, weights likelihood ** 8 (the defaults): 1.3 deg / 78 % / 10 %, 0.78."""
HEADING_PRIOR_SIGMA_DEG = 20.0
"""Sigma (deg) of a heading the user states (the API's ``heading_deg`` form field): a plain Gaussian, no floor."""
MODE_SEPARATION_M = 6.0
MODE_YAW_SEPARATION_DEG = 30.0
AMBIGUOUS_MARGIN = 5.0
"""A label whose runner-up pose scores within this factor is ambiguous: its anchors are kept for both poses.

Measured on a simulated Helsinki world (seed 1, network segmentation): of the references without a distinct
runner-up 27 of 28 had the right heading; of those with a runner-up within 2.5x, half were wrong (mostly the
mirror view across the street, which the map's geometry cannot tell apart)."""
OPEN_GROUND_EVIDENCE = 0.15
"""Below this mean facade evidence (``ImageModel.facade_present`` over its bins) a photo shows next to no facade
(open ground, far buildings beyond the map's ray cast): the map is not weighed, its GPS and compass place it."""
MODE_MIN_RELATIVE_WEIGHT = 1e-3
"""Grid modes weaker than this share of the strongest are not refined."""


@dataclass(frozen=True)
class LabelOptions:
    """How :func:`label_reference` labels a reference photo (the defaults are the measured ones above).

    gps_sigma_m: Gaussian prior on the position around the GPS tag (m; None: uniform, as the paper).
    sharpness: pose weights are likelihood ** sharpness (as the query posterior, :mod:`geoloc.localize.posterior`).
    cell_m, half_size_m: the pose grid around the tag (m). n_yaws: yaws sampled over 360 deg. sigma_m,
    normalization, use_skyline: the grid's pose likelihood (:class:`geoloc.localize.likelihood.LikelihoodOptions`;
    the continuous refinement keeps the weighted normalisation and the skyline term whatever these say).
    n_modes: the strongest distinct grid modes refined continuously.
    """

    gps_sigma_m: float | None = DEFAULT_GPS_SIGMA_M
    sharpness: float = DEFAULT_SHARPNESS
    cell_m: float = DEFAULT_REFERENCE_CELL_M
    half_size_m: float = DEFAULT_REFERENCE_HALF_SIZE_M
    n_yaws: int = 120
    sigma_m: float = DEFAULT_SIGMA_M
    normalization: str = "weighted"
    use_skyline: bool = True
    n_modes: int = 3

    @property
    def likelihood(self) -> LikelihoodOptions:
        """The grid's likelihood options (geometry only: identities are what labelling finds)."""
        return LikelihoodOptions(
            sigma_m=self.sigma_m, use_identity=False, normalization=self.normalization, use_skyline=self.use_skyline
        )


@dataclass(frozen=True)
class KnownPose:
    """A pose labelling must keep (a sequence's joint placement, :mod:`geoloc.localize.sequence`).

    x_m, y_m, yaw_deg: local metres and bearing; position_covariance: (2, 2) m^2, what the label reports.
    """

    x_m: float
    y_m: float
    yaw_deg: float
    position_covariance: np.ndarray


PLACED_LABEL_OPTIONS = LabelOptions(gps_sigma_m=1.0, half_size_m=3.0, cell_m=0.5)
"""The grid around a placed pose (:class:`KnownPose`): its identities are marginalised over these poses."""
PLACED_HEADING_SIGMA_DEG = 1.0
"""Heading sigma (deg) around a placed pose for its marginalised identities."""


@dataclass
class ReferenceLabel:
    """What labelling found for one reference photo (local frame, metres and degrees).

    x_m, y_m, yaw_deg: the refined best pose (yaw = local bearing of the optical axis).
    position_covariance: (2, 2) m^2 spread of the refined pose's position posterior (what a reference states is
    this calibrated, :mod:`geoloc.localize.label_covariance`); vp_bins: image bins that
    supported the vanishing-point yaw (0: grid yaw); mode_scores: the refined scores of the distinct grid
    modes, best first; alternative: the second distinct refined pose (often the mirror view across the
    street), or None.
    likelihood: (P, Y) pose likelihood over ``positions`` (P, 2) x ``yaws_deg`` (Y,).
    greedy, marginalized: identity maps of the photo.
    """

    x_m: float
    y_m: float
    yaw_deg: float
    best_likelihood: float
    positions: np.ndarray
    yaws_deg: np.ndarray
    likelihood: np.ndarray
    greedy: IdentityMap
    marginalized: IdentityMap
    position_covariance: np.ndarray
    vp_bins: int
    mode_scores: list[float]
    alternative: RefinedPose | None = None

    @property
    def mode_margin(self) -> float:
        """How much better the chosen pose scored than the next distinct one (inf when there was none).

        A small margin means a distinct pose (often the mirror view across the street) explains the photo
        almost as well: the label's pose, and the anchors derived from it, may be grossly wrong.
        """
        if len(self.mode_scores) < 2 or self.mode_scores[1] <= 0:
            return float("inf")
        return self.mode_scores[0] / self.mode_scores[1]

    @property
    def is_ambiguous(self) -> bool:
        """Whether a distinct pose scored within :data:`AMBIGUOUS_MARGIN` of the chosen one."""
        return self.alternative is not None and self.mode_margin < AMBIGUOUS_MARGIN


def heading_prior(
    yaws_deg: np.ndarray | float, prior_yaw_deg: float, sigma_deg: float = HEADING_PRIOR_SIGMA_DEG
) -> np.ndarray:
    """(Y,) Gaussian prior over (Y,) yaws (or a scalar yaw) around ``prior_yaw_deg`` (wrapped difference), max 1."""
    delta = (np.asarray(yaws_deg) - prior_yaw_deg + 180.0) % 360.0 - 180.0
    return np.exp(-0.5 * (delta / sigma_deg) ** 2)


def stated_heading_prior(prior_yaw_deg: float, sigma_deg: float = HEADING_PRIOR_SIGMA_DEG) -> HeadingPrior:
    """A stated heading (local bearing, deg) as a :class:`HeadingPrior`: today's Gaussian, no outlier floor.

    Its weights are bit-identical to :func:`heading_prior`'s: with eps = 0, ``(1 - 0) * g + 0 == g``.
    """
    return HeadingPrior(float(prior_yaw_deg), float(sigma_deg), 0.0)


def resolve_heading_prior(prior_yaw_deg: float | None, prior: HeadingPrior | None) -> HeadingPrior | None:
    """The one heading prior of a call that takes either a plain ``prior_yaw_deg`` or a :class:`HeadingPrior`.

    A plain yaw (local bearing, deg) is :func:`stated_heading_prior`; both at once is a ValueError.
    """
    if prior_yaw_deg is not None and prior is not None:
        raise ValueError("give prior_yaw_deg or heading_prior, not both")
    return stated_heading_prior(prior_yaw_deg) if prior_yaw_deg is not None else prior


def column_building_ids(
    panoramas: Panoramas, yaws_deg: np.ndarray, intrinsics: Intrinsics, offsets_deg: np.ndarray, bin_deg: float
) -> np.ndarray:
    """(P, Y, W) building id the map shows in each pixel column at each pose (-1: none or outside the bins)."""
    bins = column_bins(intrinsics, offsets_deg, bin_deg)  # (W,)
    window = panorama_window(panoramas, yaws_deg, offsets_deg)  # (Y, K)
    ids = panoramas.building_id[:, window]  # (P, Y, K)
    out = ids[:, :, np.maximum(bins, 0)]
    out[:, :, bins < 0] = -1
    return out


def identity_from_poses(column_ids: np.ndarray, weights: np.ndarray, building_mask: np.ndarray) -> IdentityMap:
    """Marginalise per-pose column building ids (N, W) with pose weights (N,) into an IdentityMap."""
    ids = np.unique(column_ids[column_ids >= 0])
    width = column_ids.shape[1]
    prob = np.zeros((width, len(ids)), dtype=float)
    total = weights.sum()
    if len(ids) and total > 0:
        slot = np.searchsorted(ids, column_ids)  # (N, W) index into ids where valid
        valid = column_ids >= 0
        cols = np.broadcast_to(np.arange(width)[None, :], column_ids.shape)
        w = np.broadcast_to(weights[:, None], column_ids.shape)
        np.add.at(prob, (cols[valid], slot[valid]), w[valid])
        prob /= total
    return IdentityMap(ids, prob, building_mask)


def pose_identities(
    panoramas: Panoramas,
    yaws_deg: np.ndarray,
    intrinsics: Intrinsics,
    image_model: ImageModel,
    weights: np.ndarray,
    building_mask: np.ndarray,
) -> IdentityMap:
    """:func:`identity_from_poses` of every pose of ``panoramas`` x ``yaws_deg`` with (P, Y) ``weights``.

    The same identity map as ``identity_from_poses(column_building_ids(...).reshape(-1, W), weights.ravel(),
    building_mask)``, bit for bit, without expanding the (P, Y, W) column ids: every pixel column of a bin shows
    the same building, so the weights are summed per bin (in the same order, poses first to last; poses of
    weight 0 add nothing) and the bins' rows are copied to their columns; the building ids (those seen by any
    pose, weighted or not) are read from the panorama bearings the windows cover.
    """
    bins = column_bins(intrinsics, image_model.offsets_deg, image_model.bin_deg)  # (W,)
    window = panorama_window(panoramas, yaws_deg, image_model.offsets_deg)  # (Y, K)
    used_bins = np.unique(bins[bins >= 0])
    bearings = np.unique(window[:, used_bins])
    seen = panoramas.building_id[:, bearings]
    ids = np.unique(seen[seen >= 0])
    weights = np.asarray(weights, dtype=float)
    total = weights.sum()
    prob = np.zeros((len(bins), len(ids)), dtype=float)
    if len(ids) and total > 0:
        flat_weights = weights.ravel()
        pose = np.flatnonzero(flat_weights)
        position, yaw = np.divmod(pose, len(yaws_deg))
        # Each seen bearing's slot in ids is found once per position, then gathered per pose (not searched per pose).
        column_of = np.zeros(len(panoramas.bearings_deg), dtype=np.int64)
        column_of[bearings] = np.arange(len(bearings))
        seen_slot = np.where(seen >= 0, np.searchsorted(ids, seen), -1)  # (P, seen bearings)
        slot = seen_slot[position[:, None], column_of[window[yaw][:, used_bins]]]  # (poses, used bins)
        valid = slot >= 0
        key = np.arange(len(used_bins))[None, :] * len(ids) + slot
        per_bin = np.bincount(
            key[valid],
            weights=np.repeat(flat_weights[pose], valid.sum(axis=1)),  # each pose's weight, once per valid bin
            minlength=len(used_bins) * len(ids),
        ).reshape(len(used_bins), len(ids))
        row_of_bin = np.full(len(image_model.offsets_deg), -1)
        row_of_bin[used_bins] = np.arange(len(used_bins))
        columns = bins >= 0
        prob[columns] = per_bin[row_of_bin[bins[columns]]]
        prob /= total
    return IdentityMap(ids, prob, building_mask)


def label_reference(
    city_map: CityMap,
    image_model: ImageModel,
    building_mask: np.ndarray,
    intrinsics: Intrinsics,
    gps_xy: tuple[float, float],
    *,
    prior_yaw_deg: float | None = None,
    heading_prior: HeadingPrior | None = None,
    options: LabelOptions = LabelOptions(),
    known_pose: KnownPose | None = None,
) -> ReferenceLabel:
    """Label one geo-tagged photo with the map.

    image_model: the photo's facade evidence (geometry only; identities are what we want to find).
    building_mask: (H, W) bool building pixels. gps_xy: the GPS tag in the local frame (m).
    prior_yaw_deg: optional stated heading (local bearing), Gaussian with HEADING_PRIOR_SIGMA_DEG.
    heading_prior: instead, a :class:`HeadingPrior` (e.g. the photo's compass, robust to a wrong one).
    options: the labelling's :class:`LabelOptions`.
    Poses inside building footprints are not sampled; if every grid cell is inside, the GPS tag alone is used.
    The ``options.n_modes`` strongest distinct grid modes (e.g. the wall in front and the one behind) are
    refined continuously (:func:`geoloc.localize.refinement.refine_pose`: vanishing-point yaw, 0.5 m position
    search) and the best refined pose is the label's pose.
    known_pose: a pose to keep instead (no refinement; ``gps_xy`` and the heading prior should centre on it,
    as :func:`label_known_pose` does): the label's identities are those of the grid's poses near it.
    """
    gps_sigma_m, sharpness = options.gps_sigma_m, options.sharpness
    if known_pose is None and says_little(image_model):
        sharpness = 0.0
    prior = resolve_heading_prior(prior_yaw_deg, heading_prior)
    grid = grid_around(city_map, gps_xy, options.half_size_m, options.cell_m)
    positions = grid.positions if grid.valid.any() else np.asarray([gps_xy], dtype=float)
    yaws = default_yaws_deg(options.n_yaws)
    likelihood = MapLikelihood(city_map, image_model.without_identity(), options.likelihood)
    panoramas = likelihood.panoramas(positions)
    table = likelihood.of_panoramas(panoramas, yaws)
    # Where the map says nothing (every pose's weight zero), the GPS and the compass place the photo.
    sharpened = sharpened_likelihood(table, sharpness)
    weights = sharpened if sharpened is not None else np.ones(table.shape)
    if prior is not None:
        weights = weights * prior.weights(yaws)[None, :]
    if gps_sigma_m:
        d2 = np.sum((positions - np.asarray(gps_xy, dtype=float)) ** 2, axis=1)
        weights = weights * np.exp(-0.5 * d2 / gps_sigma_m**2)[:, None]

    # Continuous refinement of the distinct grid modes; the best refined pose wins.
    best: RefinedPose | None = None
    best_score = -1.0
    refined_modes: list[tuple[float, RefinedPose]] = []
    # The refinement's likelihood keeps the weighted normalisation and the skyline term (as it always has).
    refining = likelihood.with_options(normalization="weighted", use_skyline=True)
    at_best: Panoramas | None = None  # the panorama at the label's position, when already cast
    if known_pose is not None:
        k = known_pose
        # One cast at the kept pose serves its likelihood and its greedy identities (both cast the same position).
        at_best = likelihood.panoramas(np.array([[k.x_m, k.y_m]]), np.array([k.yaw_deg]))  # its window only
        at = float(refining.of_panoramas(at_best, np.array([k.yaw_deg]))[0, 0])
        known = RefinedPose(k.x_m, k.y_m, k.yaw_deg, at, at**sharpness, np.asarray(k.position_covariance), 0)
        refined_modes.append((known.posterior, known))
        best = known
    modes = distinct_modes(positions, yaws, weights, options.n_modes) if known_pose is None else []
    for p_index, y_index in modes:
        refined = refine_pose(
            refining,
            float(positions[p_index, 0]),
            float(positions[p_index, 1]),
            float(yaws[y_index]),
            prior_xy=gps_xy if gps_sigma_m else None,
            prior_sigma_m=gps_sigma_m,
            options=RefineOptions(sharpness=sharpness),
        )
        score = refined.posterior * (1.0 if prior is None else float(prior.weights(refined.yaw_deg)))
        refined_modes.append((float(score), refined))
        if score > best_score:
            best, best_score = refined, score
    assert best is not None  # distinct_modes always yields the strongest pose

    # Identities: greedy from the refined pose; marginalised over the grid poses of the chosen mode.
    if at_best is None:
        at_best = likelihood.panoramas(np.array([[best.x_m, best.y_m]]), np.array([best.yaw_deg]))  # its window only
    greedy_ids = column_building_ids(
        at_best, np.array([best.yaw_deg]), intrinsics, image_model.offsets_deg, image_model.bin_deg
    )[0, 0]
    greedy = identity_from_poses(greedy_ids[None, :], np.ones(1), building_mask)
    in_mode = _near_pose(positions, yaws, (best.x_m, best.y_m), best.yaw_deg)
    marginal_weights = np.where(in_mode, weights, 0.0) if (weights * in_mode).sum() > 0 else weights
    marginal = pose_identities(panoramas, yaws, intrinsics, image_model, marginal_weights, building_mask)
    distinct = _distinct_refined(refined_modes)
    return ReferenceLabel(
        x_m=best.x_m,
        y_m=best.y_m,
        yaw_deg=best.yaw_deg,
        best_likelihood=best.likelihood,
        positions=positions,
        yaws_deg=yaws,
        likelihood=table,
        greedy=greedy,
        marginalized=marginal,
        position_covariance=best.position_covariance,
        vp_bins=best.vp_bins,
        mode_scores=[score for score, _ in distinct],
        alternative=distinct[1][1] if len(distinct) > 1 else None,
    )


def says_little(image_model: ImageModel) -> bool:
    """Whether the photo's mean facade evidence is under :data:`OPEN_GROUND_EVIDENCE` (the map says little of it)."""
    return float(np.mean(image_model.facade_present)) < OPEN_GROUND_EVIDENCE


def label_known_pose(
    city_map: CityMap,
    image_model: ImageModel,
    building_mask: np.ndarray,
    intrinsics: Intrinsics,
    pose: KnownPose,
) -> ReferenceLabel:
    """The label of a photo at a pose placed elsewhere (:class:`KnownPose`), which it keeps.

    Its identities are marginalised over the :data:`PLACED_LABEL_OPTIONS` grid around the pose, weighted by a
    Gaussian of :data:`PLACED_HEADING_SIGMA_DEG` around its heading.
    """
    return label_reference(
        city_map,
        image_model,
        building_mask,
        intrinsics,
        (pose.x_m, pose.y_m),
        heading_prior=HeadingPrior(pose.yaw_deg % 360.0, PLACED_HEADING_SIGMA_DEG, 0.0),
        options=PLACED_LABEL_OPTIONS,
        known_pose=pose,
    )


def _distinct_refined(refined: list[tuple[float, RefinedPose]]) -> list[tuple[float, RefinedPose]]:
    """The refined modes, best first, counting modes that refined to the same pose once."""
    kept: list[tuple[float, RefinedPose]] = []
    for score, pose in sorted(refined, key=lambda item: -item[0]):
        same = any(
            np.hypot(pose.x_m - other.x_m, pose.y_m - other.y_m) < MODE_SEPARATION_M / 2.0
            and abs((pose.yaw_deg - other.yaw_deg + 180.0) % 360.0 - 180.0) < MODE_YAW_SEPARATION_DEG / 2.0
            for _, other in kept
        )
        if not same:
            kept.append((score, pose))
    return kept


def distinct_modes(
    positions: np.ndarray,
    yaws_deg: np.ndarray,
    weights: np.ndarray,
    n_modes: int,
    min_separation_m: float = MODE_SEPARATION_M,
    min_yaw_separation_deg: float = MODE_YAW_SEPARATION_DEG,
) -> list[tuple[int, int]]:
    """Up to ``n_modes`` (position index, yaw index) local maxima of a (P, Y) weight table, strongest first.

    Two poses belong to the same mode when they are within ``min_separation_m`` and ``min_yaw_separation_deg``.
    """
    remaining = np.asarray(weights, dtype=float).copy()
    modes: list[tuple[int, int]] = []
    top = float(remaining.max(initial=0.0))
    while len(modes) < n_modes:
        p_index, y_index = np.unravel_index(int(np.argmax(remaining)), remaining.shape)
        value = remaining[p_index, y_index]
        # The strongest pose is always a mode (even when nothing fits: the photo must get a pose).
        if modes and (value <= 0 or value < MODE_MIN_RELATIVE_WEIGHT * top):
            break
        modes.append((int(p_index), int(y_index)))
        remaining[
            _near_pose(
                positions, yaws_deg, positions[p_index], yaws_deg[y_index], min_separation_m, min_yaw_separation_deg
            )
        ] = 0.0
    return modes


def _near_pose(
    positions: np.ndarray,
    yaws_deg: np.ndarray,
    xy: tuple[float, float] | np.ndarray,
    yaw_deg: float,
    separation_m: float = MODE_SEPARATION_M,
    yaw_separation_deg: float = MODE_YAW_SEPARATION_DEG,
) -> np.ndarray:
    """(P, Y) bool: poses within ``separation_m`` and ``yaw_separation_deg`` of a pose."""
    near_xy = np.hypot(*(positions - np.asarray(xy, dtype=float)).T) < separation_m
    near_yaw = np.abs((np.asarray(yaws_deg) - yaw_deg + 180.0) % 360.0 - 180.0) < yaw_separation_deg
    near: np.ndarray = near_xy[:, None] & near_yaw[None, :]
    return near
