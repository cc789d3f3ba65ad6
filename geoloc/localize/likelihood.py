"""Camera pose likelihood p(I | x, y, yaw): the paper's weighted intersection over union (Eq. 3-5).

Per angular column bin k of the image (see :mod:`geoloc.vision.image_model`) and a pose g:

- Z_k: the map facade the ray at bearing ``yaw + offset_k`` hits first (from the panoramas), its
  orientation relative to the camera theta_k, building b_k and distance d_k;
  w_k = exp(-d_k^2 / (2 sigma^2)), the N(0, sigma) weight (far facades count less).
- Zhat_k: the image's facade evidence, ``facade_present`` c_k in [0, 1] and orientation theta_hat_k.

    S    = sum_k c_k * 1(Z_k) * |cos(theta_k - theta_hat_k)| * w_k * m_k
    Smax = sum_k [ c_k + (1 - c_k) * 1(Z_k) * w_k ]                       (normalization="paper")
    Smax = sum_k [ c_k * (1(Z_k) * w_k + 1(not Z_k)) + (1 - c_k) * 1(Z_k) * w_k ]   ("weighted")
    p(I | g) = S / Smax   (0 when Smax = 0)

With a binary c_k, "paper" is exactly the paper's formula. Its first Smax term does not carry the
distance weight, so even a perfect image model scores only the mean weight of its columns at the
true pose, and poses nearer to the walls are favoured. "weighted" (the default) is a weighted
intersection over union in which every column that has a map facade is weighted by w_k on both
sides: a perfect image model scores exactly 1 at the true pose, columns where the image sees a
facade and the map has none still cost 1, and far facades still count less. m_k = 1 for the geometry-only likelihood;
for the identity-aware one m_k = P_k(b_k) + unknown_weight * (1 - sum_b P_k(b)), the probability
that the building seen in bin k is the map's b_k (the paper's indicator, softened by identity
probabilities; ``unknown_weight`` = 0 gives the paper's hard requirement, where a column with no
identity evidence cannot match). Identities that may be wrong (``identity_trust`` t < 1) count as
t m_k + (1 - t): with t = 0 a pose that does not show the named buildings is not penalised at all.

Distance term (beyond the paper, ``use_distance``): where the image model knows a bin's facade
distance d_hat_k (from the facade's base line, :mod:`geoloc.vision.ground`), S's term is also multiplied by
exp(-(ln d_k - ln d_hat_k)^2 / (2 s^2)), s = ``distance_sigma_log``, with the deviation scaled by
``DISTANCE_NEAR_SLACK`` where the map's facade is nearer than the image's (segmentation tends to end a
building above its true base, which lengthens the image's distance; measured on simulated worlds with the
network's labels: 57 % of columns 10 % too far, 5 % 10 % too near). It separates poses that see the
same walls at the same angles but at other distances, e.g. facing the wall across the street instead
of the one behind; Smax is unchanged, so a perfect model still scores 1 at the true pose.

Skyline term (beyond the paper, ``building_height_m``): where the image sees a bin's building top
against the sky at elevation e_hat_k (:func:`geoloc.vision.ground.facade_top_elevations`) and the map knows
the height H_k of the building hit there (a tagged ``height`` or ``building:levels``; default heights
are not evidence), the facade's distance is (H_k - h) / tan(e_hat_k) for a camera at height h. S's
term is multiplied by exp(-(ln(d_k tan e_hat_k) - ln(H_k - h))^2 / (2 s_h^2)), s_h =
``height_sigma_log``. It works where the base line is hidden and tells buildings of different heights
apart; Smax is unchanged. A taller building behind a lower one shows its top above the lower one's:
the observed top is then higher than the map's first hit predicts, so only the opposite disagreement
(seen lower than the map's building) is penalised at full weight.

All positions x yaws are evaluated in one call (a compiled kernel;
:func:`geoloc.localize.likelihood_reference.pose_likelihood_numpy` is the same formula in plain numpy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

from geoloc.core.camera import wrap_orientation_deg
from geoloc.maps import CityMap
from geoloc.maps.raycast import Panoramas, panorama_window
from geoloc.maps.spatial import unique_ids
from geoloc.vision.image_model import ImageModel

DEFAULT_SIGMA_M = 40.0
"""Distance weight scale: a facade 40 m away counts exp(-1/2) = 0.61, one at 80 m 0.14."""

DEFAULT_UNKNOWN_WEIGHT = 0.0
DEFAULT_DISTANCE_SIGMA_LOG = 0.3
"""Spread of the distance term in log distance: a facade 35 % nearer or farther than seen scores 0.6."""
DISTANCE_NEAR_SLACK = 0.3
"""Factor on the distance term's deviation where the map's facade is nearer than the image's estimate."""
DEFAULT_HEIGHT_SIGMA_LOG = 0.15
"""Spread of the skyline term in log height above the camera (a storey in five)."""
CAMERA_HEIGHT_M = 1.6
NORMALIZATIONS = ("weighted", "paper")


def default_yaws_deg(n_yaws: int = 120) -> np.ndarray:
    """``n_yaws`` camera yaws evenly over 360 deg (paper: 120, i.e. every 3 deg)."""
    return np.arange(n_yaws) * (360.0 / n_yaws)


@dataclass(frozen=True)
class LikelihoodOptions:
    """How the likelihood scores a pose (module docstring): one options object, passed whole.

    sigma_m: distance weight scale (m). use_identity: the identity-aware likelihood where the image model
    carries identities (False: the paper's geometry-only one). identity_trust: the chance that the model's
    identities are right: each bin's identity factor m_k becomes ``identity_trust * m_k + (1 - identity_trust)``
    (1: as given; 0: the geometry-only likelihood). unknown_weight, normalization ("weighted" or
    "paper"), use_distance, distance_sigma_log: see the module docstring. use_skyline: the skyline term where
    building heights are known (``building_height_m``); height_sigma_log: its spread.
    """

    sigma_m: float = DEFAULT_SIGMA_M
    use_identity: bool = True
    identity_trust: float = 1.0
    unknown_weight: float = DEFAULT_UNKNOWN_WEIGHT
    normalization: str = "weighted"
    use_distance: bool = True
    distance_sigma_log: float = DEFAULT_DISTANCE_SIGMA_LOG
    use_skyline: bool = True
    height_sigma_log: float = DEFAULT_HEIGHT_SIGMA_LOG


def pose_likelihood(
    panoramas: Panoramas,
    image_model: ImageModel,
    yaws_deg: np.ndarray | None = None,
    options: LikelihoodOptions = LikelihoodOptions(),
    building_height_m: np.ndarray | None = None,
) -> np.ndarray:
    """p(I | g) for every position of ``panoramas`` and every yaw: array (P, Y) in [0, 1].

    panoramas: map panoramas at P positions (bearing step must match ``image_model.bin_deg``
        or divide it evenly: bins are looked up by rounding to the panorama step).
    image_model: the photo's per-bin evidence. Identities are used if present and ``options.use_identity``.
    yaws_deg: (Y,) camera yaws, bearing of the optical axis in the local frame (default 120 yaws).
    options: the likelihood's :class:`LikelihoodOptions`. building_height_m: (B,) height of each map
    building where it is known (NaN where the map only has a default), enabling the skyline term (with
    ``options.use_skyline``). :class:`geoloc.localize.map_likelihood.MapLikelihood` binds a map, an image
    model and the options, and casts the panoramas.

    A compiled kernel (:func:`_likelihood_kernel`) evaluates the terms per (position, yaw, bin) in one pass,
    skipping bins where nothing can score; what does not depend on the yaw (distance weights, log
    distances) is computed once per panorama bearing.
    :func:`geoloc.localize.likelihood_reference.pose_likelihood_numpy` is the same formula in plain numpy (the
    specification, and the reference of the tests and of ``benchmarks/bench_core.py``): the two agree to float32
    rounding.
    """
    terms = _terms(panoramas, image_model, yaws_deg, options, building_height_m)
    inv_two_sigma2 = 1.0 / (2.0 * options.sigma_m**2)
    # Per panorama bearing, as pose_likelihood_numpy computes them per (position, yaw, bin): same bits. Only the
    # bearings the window reads (a few yaws read a camera's field of view, not the whole panorama).
    window, read = terms.window, unique_ids(terms.window, panoramas.distance_m.shape[1])
    used: np.ndarray | slice = slice(None)  # the whole panorama: no copy
    if len(read) < panoramas.distance_m.shape[1]:
        used, window = read, np.searchsorted(read, window)
    dist = panoramas.distance_m[:, used]
    hit = np.isfinite(dist)
    weight = np.where(hit, np.exp(-np.square(np.where(hit, dist, 0.0)) * inv_two_sigma2), 0.0)
    log_distance = np.log(np.where(hit, np.maximum(dist, 0.1), 1.0))
    # |cos(theta - theta_hat)| = |cos(normal - (yaw + theta_hat))| (theta = normal - yaw modulo 180 deg), expanded
    # as cos a cos b + sin a sin b: one cosine per bearing and one per (yaw, bin) instead of one per term.
    normal = np.radians(np.where(hit, panoramas.normal_bearing_deg[:, used], 0.0).astype(np.float64))
    view = np.radians(terms.yaws[:, None] + terms.theta_hat[None, :].astype(np.float64))  # (Y, K)
    empty = np.zeros(0, np.float32)
    out = np.zeros((len(panoramas), len(terms.yaws)), dtype=np.float32)
    _likelihood_kernel(
        window,
        np.ascontiguousarray(weight, dtype=np.float32),
        hit,
        np.ascontiguousarray(log_distance, dtype=np.float32),
        np.cos(normal),
        np.sin(normal),
        np.cos(view),
        np.sin(view),
        np.ascontiguousarray(panoramas.building_id[:, used], dtype=np.int32),
        terms.present,
        empty if terms.log_distance_hat is None else terms.log_distance_hat,
        np.float32(options.distance_sigma_log),
        empty if terms.log_top_hat is None else terms.log_top_hat,
        empty if terms.log_rise is None else terms.log_rise,
        np.float32(options.height_sigma_log),
        np.zeros((0, 0), np.float32) if terms.identity_lut is None else terms.identity_lut,
        options.normalization == "paper",
        out,
    )
    return out


@dataclass
class _Terms:
    """The image side of the likelihood and the panorama window, shared by the kernel and the numpy form."""

    yaws: np.ndarray  # (Y,) float64
    window: np.ndarray  # (Y, K) bearing indices
    present: np.ndarray  # (K,) float32 in [0, 1]
    theta_hat: np.ndarray  # (K,) float32
    log_distance_hat: np.ndarray | None  # (K,) float32, NaN where unknown
    identity_lut: np.ndarray | None  # (K, B + 1) float32
    log_rise: np.ndarray | None  # (B + 1,) float32, NaN where unknown
    log_top_hat: np.ndarray | None  # (K,) float32


def _terms(
    panoramas: Panoramas,
    image_model: ImageModel,
    yaws_deg: np.ndarray | None,
    options: LikelihoodOptions,
    building_height_m: np.ndarray | None,
) -> _Terms:
    if options.normalization not in NORMALIZATIONS:
        raise ValueError(f"normalization must be one of {NORMALIZATIONS}, got {options.normalization!r}")
    yaws = default_yaws_deg() if yaws_deg is None else np.asarray(yaws_deg, dtype=float)
    window = panorama_window(panoramas, yaws, image_model.offsets_deg)  # (Y, K)
    present = np.clip(image_model.facade_present, 0.0, 1.0).astype(np.float32)  # (K,)
    theta_hat = image_model.orientation_deg.astype(np.float32)
    identity_lut = None
    log_distance_hat = None
    if options.use_distance and image_model.distance_m is not None and np.isfinite(image_model.distance_m).any():
        log_distance_hat = np.log(image_model.distance_m).astype(np.float32)  # NaN where unknown
    if options.use_identity and image_model.has_identity:
        identity_lut = _identity_lookup(image_model, panoramas, options.unknown_weight, options.identity_trust)
    skyline = _skyline_logs(image_model, building_height_m if options.use_skyline else None)
    log_rise, log_top_hat = skyline if skyline is not None else (None, None)
    return _Terms(yaws, window, present, theta_hat, log_distance_hat, identity_lut, log_rise, log_top_hat)


@numba.njit(cache=True, nogil=True)
def _likelihood_kernel(  # noqa: C901, PLR0912 - one compiled loop nest; numba gains from keeping it whole
    window: np.ndarray,
    weight: np.ndarray,
    hit: np.ndarray,
    log_distance: np.ndarray,
    cos_normal: np.ndarray,
    sin_normal: np.ndarray,
    cos_view: np.ndarray,
    sin_view: np.ndarray,
    building: np.ndarray,
    present: np.ndarray,
    log_distance_hat: np.ndarray,
    distance_sigma_log: np.float32,
    log_top_hat: np.ndarray,
    log_rise: np.ndarray,
    height_sigma_log: np.float32,
    identity_lut: np.ndarray,
    paper: bool,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled; checked against likelihood_reference in the tests
    """out[p, y] = S / Smax (module docstring) for every position p and yaw y; float32 terms as in numpy.

    cos_normal, sin_normal: (P, N) of the hit facades' normal bearings; cos_view, sin_view: (Y, K) of yaw plus
    the image's orientation per bin (their difference is the angle whose |cos| the agreement is).
    """
    n_bins = window.shape[1]
    use_distance = log_distance_hat.shape[0] > 0
    use_skyline = log_rise.shape[0] > 0
    use_identity = identity_lut.shape[0] > 0
    present_sum = 0.0
    for k in range(n_bins):
        present_sum += present[k]
    near_slack = np.float32(DISTANCE_NEAR_SLACK)
    half = np.float32(-0.5)
    for p in range(weight.shape[0]):
        for y in range(window.shape[0]):
            s = 0.0
            s_max = present_sum if paper else 0.0
            for k in range(n_bins):
                b = window[y, k]
                w = weight[p, b]
                if paper:
                    s_max += (1.0 - present[k]) * w
                elif hit[p, b]:
                    s_max += w
                else:
                    s_max += present[k]
                if not hit[p, b] or present[k] == 0.0:
                    continue
                agree = abs(cos_normal[p, b] * cos_view[y, k] + sin_normal[p, b] * sin_view[y, k])
                score = np.float64(w) * agree * np.float64(present[k])
                if use_distance:
                    z = (log_distance[p, b] - log_distance_hat[k]) / distance_sigma_log
                    if np.isfinite(z):
                        if z < 0:
                            z = near_slack * z
                        score *= np.float64(np.exp(half * (z * z)))
                if use_skyline:
                    z = (log_distance[p, b] + log_top_hat[k] - log_rise[building[p, b] + 1]) / height_sigma_log
                    if np.isfinite(z):
                        if z > 0:
                            z = np.float32(0.25) * z
                        score *= np.float64(np.exp(half * (z * z)))
                if use_identity:
                    score *= np.float64(identity_lut[k, building[p, b] + 1])
                s += score
            out[p, y] = s / max(s_max, 1e-12) if s_max > 0 else 0.0


def known_building_heights(city_map: CityMap) -> np.ndarray:
    """(B,) building heights where the map states them (``height`` or ``building:levels``), NaN for defaults.

    Read-only, computed once per map (:attr:`geoloc.maps.model.CityMap.known_building_height_m`).
    """
    return city_map.known_building_height_m


def _skyline_logs(
    image_model: ImageModel, building_height_m: np.ndarray | None
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]] | None:
    """What the skyline term compares, or None when there is nothing to compare.

    Returns (B + 1,) ln(height above the camera, m) per map building (column 0: no hit; NaN where the
    height is unknown or too low to tell) and (K,) ln(tan elevation) of the image's building top per bin.
    """
    top_hat = image_model.top_tan_elevation
    if building_height_m is None or top_hat is None or not np.isfinite(top_hat).any():
        return None
    rise = np.asarray(building_height_m, dtype=np.float64) - CAMERA_HEIGHT_M
    # Column 0: no hit; unknown or too low buildings give NaN (no evidence).
    log_rise = np.concatenate([[np.nan], np.where(rise > 0.5, np.log(np.maximum(rise, 0.5)), np.nan)])
    return log_rise.astype(np.float32), np.log(top_hat).astype(np.float32)


def _identity_lookup(
    image_model: ImageModel, panoramas: Panoramas, unknown_weight: float, trust: float = 1.0
) -> np.ndarray:
    """(K, B + 1) table: match probability of bin k with map building b (column b + 1; column 0 = no hit).

    trust: :attr:`LikelihoodOptions.identity_trust` (the table is ``trust * m + (1 - trust)`` where a facade is hit).
    """
    if image_model.identity_prob is None or image_model.identity_building_ids is None:
        raise ValueError("the image model carries no building identities")
    n_buildings = int(max(panoramas.building_id.max(initial=-1), image_model.identity_building_ids.max(initial=-1))) + 1
    prob = np.clip(image_model.identity_prob, 0.0, 1.0)
    unknown = np.clip(1.0 - prob.sum(axis=1), 0.0, 1.0) * unknown_weight  # (K,)
    lut = np.repeat(unknown[:, None], n_buildings + 1, axis=1).astype(np.float32)
    ids = np.asarray(image_model.identity_building_ids, dtype=np.int64)
    lut[:, ids + 1] += prob
    lut = np.clip(lut, 0.0, 1.0)
    if trust < 1.0:
        lut = (trust * lut + (1.0 - trust)).astype(np.float32)
    lut[:, 0] = 0.0
    return lut


def image_model_from_map(
    panoramas: Panoramas,
    position_index: int,
    yaw_deg: float,
    offsets_deg: np.ndarray,
    with_identity: bool = True,
    with_distance: bool = False,
    bin_deg: float | None = None,
) -> ImageModel:
    """The image model a perfect image analysis would give at a pose (position ``position_index``, yaw).

    Every bin whose ray hits a facade is present with confidence 1 and that facade's orientation; with
    ``with_identity`` the identity is the hit building with probability 1; with ``with_distance`` every hit
    bin knows its facade distance. Used for tests and as the ground-truth image model in evaluation.
    """
    window = panorama_window(panoramas, np.array([yaw_deg]), offsets_deg)[0]
    building = panoramas.building_id[position_index, window]
    hit = building >= 0
    theta = wrap_orientation_deg(panoramas.normal_bearing_deg[position_index, window] - yaw_deg)
    ids = prob = None
    if with_identity:
        ids = np.unique(building[hit])
        prob = (building[:, None] == ids[None, :]).astype(float)
    return ImageModel(
        offsets_deg=np.asarray(offsets_deg, dtype=float),
        facade_present=hit.astype(float),
        orientation_deg=np.where(hit, theta, 0.0),
        identity_building_ids=ids,
        identity_prob=prob,
        distance_m=np.where(hit, panoramas.distance_m[position_index, window], np.nan) if with_distance else None,
        bin_deg=bin_deg or panoramas.bearing_step_deg,
    )
