"""Facade orientation accuracy of an image model against per-column ground truth (``geoloc eval facades``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from geoloc.core.camera import Intrinsics, wrap_orientation_deg
from geoloc.vision.image_model import ImageModel, column_bins


@dataclass
class OrientationErrors:
    """Facade orientation accuracy against ground truth, per pixel column.

    median_abs_error_deg: median |theta_hat - theta| (mod 180, in [0, 90]) over GT building columns
        that have a hypothesis; within_5deg / within_10deg: share of those columns within 5 / 10 deg;
    coverage: share of GT building columns that have a hypothesis at all;
    n_building_columns / n_evaluated_columns: the counts behind them.
    """

    median_abs_error_deg: float
    within_5deg: float
    within_10deg: float
    coverage: float
    n_building_columns: int
    n_evaluated_columns: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (floats rounded to 4 decimals)."""
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def column_orientation_errors(
    pred_model: ImageModel,
    gt_column_orientation_deg: np.ndarray,
    gt_column_is_building: np.ndarray,
    intrinsics: Intrinsics,
    min_confidence: float = 0.0,
) -> tuple[np.ndarray, int, int]:
    """Per-column errors behind :func:`orientation_errors` (same arguments), for pooling over images.

    Returns (|theta_hat - theta| mod 180 in deg of every evaluated column, number of GT building columns
    inside the model's bins, number of those with a hypothesis).
    """
    gt_theta = np.asarray(gt_column_orientation_deg, dtype=float)
    gt_bld = np.asarray(gt_column_is_building, dtype=bool)
    if gt_theta.shape != (intrinsics.width,) or gt_bld.shape != (intrinsics.width,):
        raise ValueError("ground truth must have one value per pixel column")
    bins = column_bins(intrinsics, pred_model.offsets_deg, pred_model.bin_deg)
    inside = bins >= 0
    safe = np.maximum(bins, 0)
    has_hyp = inside & (pred_model.facade_present[safe] > min_confidence)
    building = gt_bld & inside
    evaluated = building & has_hyp & np.isfinite(gt_theta)
    err = np.abs(wrap_orientation_deg(pred_model.orientation_deg[safe] - gt_theta))[evaluated]
    return err, int(building.sum()), int((building & has_hyp).sum())


def orientation_errors(
    pred_model: ImageModel,
    gt_column_orientation_deg: np.ndarray,
    gt_column_is_building: np.ndarray,
    intrinsics: Intrinsics,
    min_confidence: float = 0.0,
) -> OrientationErrors:
    """Compare a predicted image model with per-pixel-column ground truth.

    pred_model: the image model (angular bins); gt_column_orientation_deg: (W,) true theta per pixel
    column (deg, NaN allowed where unknown); gt_column_is_building: (W,) whether the column shows a
    building; intrinsics: of the image (W = width). A column has a hypothesis when its bin's
    ``facade_present > min_confidence``. Columns outside the model's bins are ignored.
    """
    err, n_b, n_covered = column_orientation_errors(
        pred_model, gt_column_orientation_deg, gt_column_is_building, intrinsics, min_confidence
    )
    n_e = len(err)
    return OrientationErrors(
        median_abs_error_deg=float(np.median(err)) if n_e else float("nan"),
        within_5deg=float(np.mean(err <= 5.0)) if n_e else 0.0,
        within_10deg=float(np.mean(err <= 10.0)) if n_e else 0.0,
        coverage=n_covered / n_b if n_b else float("nan"),
        n_building_columns=n_b,
        n_evaluated_columns=n_e,
    )
