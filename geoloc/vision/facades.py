"""The image side of the method on one photo.

Line segments, vanishing points (without clutter), facade decomposition
(:mod:`geoloc.vision.decomposition`) and the per-column image model (:mod:`geoloc.vision.image_model`), with
timings.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.vision.clutter import estimate_scene_vanishing_points
from geoloc.vision.decomposition import DecompositionOptions, FacadeDecomposition, decompose_facades
from geoloc.vision.image_model import DEFAULT_BIN_DEG, ImageModel, image_model_from_columns
from geoloc.vision.lines import detect_line_segments
from geoloc.vision.vanishing import VanishingPoints


@dataclass
class ImageAnalysis:
    """Everything the image side of the likelihood derives from one photo."""

    intrinsics: Intrinsics
    segments: np.ndarray
    vanishing_points: VanishingPoints
    decomposition: FacadeDecomposition
    image_model: ImageModel
    timings_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary (no per-pixel arrays)."""
        intr = self.intrinsics
        m = self.image_model
        return {
            "image": {"width": intr.width, "height": intr.height},
            "intrinsics": {
                "focal_px": round(intr.focal_px, 2),
                "hfov_deg": round(intr.hfov_deg, 3),
                "source": intr.source,
            },
            "n_segments": len(self.segments),
            "n_building_segments": int(self.decomposition.building_segments.sum()),
            "vanishing_points": self.vanishing_points.to_dict(intr),
            "facades": self.decomposition.to_dict(),
            "image_model": {
                "bin_deg": m.bin_deg,
                "n_bins": m.n_bins,
                "share_bins_with_facade": round(float(np.mean(m.facade_present > 0)), 4),
                "mean_confidence": round(float(np.mean(m.facade_present)), 4),
            },
            "timings_s": {k: round(v, 4) for k, v in self.timings_s.items()},
        }


def _as_segments(segments_or_image: np.ndarray) -> tuple[np.ndarray, bool]:
    """Return (segments, was_image): an (N, 4) float array is taken as segments, anything else as an image."""
    arr = np.asarray(segments_or_image)
    is_segments = arr.ndim == 2 and arr.shape[1] == 4 and arr.dtype.kind == "f"
    if is_segments:
        return arr.astype(float), False
    return detect_line_segments(arr), True


def facade_image_model(
    labels: np.ndarray,
    segments_or_image: np.ndarray,
    intrinsics: Intrinsics,
    vanishing_points: VanishingPoints | None = None,
    bin_deg: float = DEFAULT_BIN_DEG,
    decomposition: DecompositionOptions = DecompositionOptions(),
) -> tuple[ImageModel, FacadeDecomposition]:
    """Per-column facade image model of an image.

    labels: (H, W) class codes; segments_or_image: (N, 4) float segments (px) or the image itself
    ((H, W) / (H, W, 3), segments are then detected); intrinsics: of that image (width/height must
    match ``labels``); vanishing_points: reuse already estimated VPs for these segments (default:
    :func:`estimate_scene_vanishing_points`, i.e. without segments on trees, cars and sky); decomposition: the
    options of :func:`decompose_facades`. Returns the binned :class:`ImageModel` (``bin_deg`` wide angular bins)
    and the decomposition.
    """
    lab = np.asarray(labels)
    if lab.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f"labels {lab.shape} do not match the intrinsics ({intrinsics.height}, {intrinsics.width})")
    segments, _ = _as_segments(segments_or_image)
    vps = vanishing_points
    if vps is None:
        vps = estimate_scene_vanishing_points(lab, segments, intrinsics)
    deco = decompose_facades(lab, segments, vps, intrinsics, decomposition)
    model = image_model_from_columns(
        intrinsics, deco.column_present, np.nan_to_num(deco.column_theta_deg), bin_deg=bin_deg
    )
    model.meta.update(
        {
            "pitch_deg": float(vps.pitch_deg),
            "roll_deg": float(vps.roll_deg),
            "n_pieces": len(deco.pieces),
            "hfov_deg": float(intrinsics.hfov_deg),
        }
    )
    return model, deco


def analyze_image(
    image_rgb: np.ndarray,
    labels: np.ndarray,
    intrinsics: Intrinsics,
    bin_deg: float = DEFAULT_BIN_DEG,
    segments: np.ndarray | None = None,
    decomposition: DecompositionOptions = DecompositionOptions(),
) -> ImageAnalysis:
    """Full image side of the method: segments, VPs, facade decomposition and image model.

    image_rgb: (H, W, 3) uint8 RGB (or gray); labels: (H, W) class codes (resized with nearest
    neighbour if their size differs); intrinsics: of the image (rescaled if its size differs);
    segments: ``detect_line_segments(image_rgb)`` when already detected (they need no labels: e.g. beside the
    segmentation network), else detected here; decomposition: the options of :func:`decompose_facades`.
    """
    import cv2

    img = np.asarray(image_rgb)
    h, w = img.shape[:2]
    if (intrinsics.width, intrinsics.height) != (w, h):
        intrinsics = intrinsics.scaled(w, h)
    lab = np.asarray(labels)
    if lab.shape != (h, w):
        lab = cv2.resize(lab.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if segments is None:
        segments = detect_line_segments(img)
    t1 = time.perf_counter()
    vps = estimate_scene_vanishing_points(lab, segments, intrinsics)
    t2 = time.perf_counter()
    model, deco = facade_image_model(
        lab, segments, intrinsics, vanishing_points=vps, bin_deg=bin_deg, decomposition=decomposition
    )
    t3 = time.perf_counter()
    timings.update({"lines": t1 - t0, "vanishing_points": t2 - t1, "facades": t3 - t2})
    return ImageAnalysis(intrinsics, segments, vps, deco, model, timings)
