"""The image model: what a photo says about facades, per angular column bin.

The likelihood compares this with the map panoramas. Columns are binned by viewing angle
(``bin_deg``, default 0.5 deg, the panorama bearing step), so a camera yaw selects a contiguous
window of a panorama. Bin ``k`` covers column angles ``offsets_deg[k] +- bin_deg / 2`` (right of the
optical axis, see :mod:`geoloc.core.camera`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geoloc.core.camera import Intrinsics, wrap_orientation_deg

DEFAULT_BIN_DEG = 0.5


@dataclass
class ImageModel:
    """Per angular bin of one image.

    offsets_deg: (K,) bin centres, deg right of the optical axis, multiples of ``bin_deg``.
    facade_present: (K,) in [0, 1]; 0 = no facade hypothesis in that bin, else its confidence.
    orientation_deg: (K,) facade orientation theta_hat relative to the camera (deg, [-90, 90)),
        meaningful where ``facade_present > 0``.
    identity_building_ids: (M,) building ids the identity columns refer to (or ``None``).
    identity_prob: (K, M) probability that the facade in bin k belongs to each of those buildings
        (rows may sum to less than 1: the rest is "unknown"), or ``None`` for geometry only.
    distance_m: (K,) horizontal distance of the facade in bin k estimated from the image (NaN where
        unknown; see :mod:`geoloc.vision.ground`), or ``None``.
    top_tan_elevation: (K,) tangent of the elevation angle of the building's top edge against the sky in
        bin k (NaN where not seen; :func:`geoloc.vision.ground.facade_top_elevations`), or ``None``.
    """

    offsets_deg: np.ndarray
    facade_present: np.ndarray
    orientation_deg: np.ndarray
    identity_building_ids: np.ndarray | None = None
    identity_prob: np.ndarray | None = None
    distance_m: np.ndarray | None = None
    top_tan_elevation: np.ndarray | None = None
    bin_deg: float = DEFAULT_BIN_DEG
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Check that every per-bin array has one value per bin; ValueError if not."""
        k = len(self.offsets_deg)
        if self.facade_present.shape != (k,) or self.orientation_deg.shape != (k,):
            raise ValueError("facade_present and orientation_deg must have one value per bin")
        if (self.identity_prob is None) != (self.identity_building_ids is None):
            raise ValueError("identity_prob and identity_building_ids go together")
        if (
            self.identity_prob is not None
            and self.identity_building_ids is not None
            and self.identity_prob.shape != (k, len(self.identity_building_ids))
        ):
            raise ValueError("identity_prob must be (bins, buildings)")
        if self.distance_m is not None and self.distance_m.shape != (k,):
            raise ValueError("distance_m must have one value per bin")
        if self.top_tan_elevation is not None and self.top_tan_elevation.shape != (k,):
            raise ValueError("top_tan_elevation must have one value per bin")

    @property
    def n_bins(self) -> int:
        """Number of bearing bins."""
        return len(self.offsets_deg)

    @property
    def has_identity(self) -> bool:
        """Whether the model carries building identity probabilities."""
        return self.identity_prob is not None

    def without_identity(self) -> ImageModel:
        """The same model without building identities (facade geometry and distances only)."""
        return ImageModel(
            self.offsets_deg,
            self.facade_present,
            self.orientation_deg,
            distance_m=self.distance_m,
            top_tan_elevation=self.top_tan_elevation,
            bin_deg=self.bin_deg,
        )


def bin_offsets_deg(intrinsics: Intrinsics, bin_deg: float = DEFAULT_BIN_DEG) -> np.ndarray:
    """Centres (deg) of the angular bins that cover the image's horizontal field of view.

    Bins are centred on multiples of ``bin_deg`` so that they align with panorama bearings.
    """
    half = intrinsics.hfov_deg / 2.0
    n = int(np.floor(half / bin_deg))
    return np.arange(-n, n + 1) * bin_deg


def column_bins(intrinsics: Intrinsics, offsets_deg: np.ndarray, bin_deg: float = DEFAULT_BIN_DEG) -> np.ndarray:
    """For each pixel column, the index of its angular bin in ``offsets_deg`` (-1 if outside)."""
    angles = intrinsics.column_angle_deg(np.arange(intrinsics.width) + 0.5)
    index: np.ndarray = np.round((angles - offsets_deg[0]) / bin_deg).astype(int)
    index[(index < 0) | (index >= len(offsets_deg))] = -1
    return index


def image_model_from_columns(
    intrinsics: Intrinsics,
    column_present: np.ndarray,
    column_orientation_deg: np.ndarray,
    column_identity_prob: np.ndarray | None = None,
    identity_building_ids: np.ndarray | None = None,
    column_distance_m: np.ndarray | None = None,
    bin_deg: float = DEFAULT_BIN_DEG,
    column_top_tan_elevation: np.ndarray | None = None,
) -> ImageModel:
    """Bin per-pixel-column facade evidence into an :class:`ImageModel`.

    column_present: (W,) confidence in [0, 1] that a facade covers the column.
    column_orientation_deg: (W,) theta_hat per column (deg), used where present.
    column_identity_prob: optional (W, M) identity probabilities per column.
    column_distance_m: optional (W,) facade distance per column (NaN unknown); a bin takes the geometric
    mean of its known columns.
    column_top_tan_elevation: optional (W,) tangent of the top edge's elevation (NaN unknown); a bin takes
    the mean of its known columns.
    Orientations are averaged as doubled angles (they are defined modulo 180), weighted by
    confidence; presence and identities are averaged over the columns of a bin.
    """
    offsets = bin_offsets_deg(intrinsics, bin_deg)
    bins = column_bins(intrinsics, offsets, bin_deg)
    valid = bins >= 0
    k = len(offsets)
    counts = np.bincount(bins[valid], minlength=k).astype(float)
    safe_counts = np.maximum(counts, 1.0)
    present = np.clip(np.asarray(column_present, dtype=float), 0.0, 1.0)
    present_sum = np.bincount(bins[valid], weights=present[valid], minlength=k)
    doubled = np.radians(2.0 * np.asarray(column_orientation_deg, dtype=float))
    doubled = np.where(np.isfinite(doubled), doubled, 0.0)
    c = np.bincount(bins[valid], weights=(present * np.cos(doubled))[valid], minlength=k)
    s = np.bincount(bins[valid], weights=(present * np.sin(doubled))[valid], minlength=k)
    orientation = wrap_orientation_deg(np.degrees(np.arctan2(s, c)) / 2.0)
    identity = None
    if column_identity_prob is not None:
        prob = np.asarray(column_identity_prob, dtype=float)
        identity = np.zeros((k, prob.shape[1]))
        np.add.at(identity, bins[valid], prob[valid])
        identity /= safe_counts[:, None]
    distance = None
    if column_distance_m is not None:
        known = valid & np.isfinite(column_distance_m) & (np.asarray(column_distance_m) > 0)
        log_sum = np.bincount(bins[known], weights=np.log(np.asarray(column_distance_m)[known]), minlength=k)
        n_known = np.bincount(bins[known], minlength=k)
        with np.errstate(invalid="ignore", divide="ignore"):
            distance = np.where(n_known > 0, np.exp(log_sum / np.maximum(n_known, 1)), np.nan)
    top = None
    if column_top_tan_elevation is not None:
        tops = np.asarray(column_top_tan_elevation, dtype=float)
        known = valid & np.isfinite(tops)
        top_sum = np.bincount(bins[known], weights=tops[known], minlength=k)
        n_top = np.bincount(bins[known], minlength=k)
        top = np.where(n_top > 0, top_sum / np.maximum(n_top, 1), np.nan)
    return ImageModel(
        offsets_deg=offsets,
        facade_present=present_sum / safe_counts,
        orientation_deg=orientation,
        identity_building_ids=None if identity is None else np.asarray(identity_building_ids),
        identity_prob=identity,
        distance_m=distance,
        top_tan_elevation=top,
        bin_deg=bin_deg,
    )
