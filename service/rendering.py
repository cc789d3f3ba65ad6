"""Images the API returns: identity overlays of references."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageOps

from contracts.references import ReferenceLabelArrays


def building_colors(building_ids: np.ndarray) -> np.ndarray:
    """A stable, distinct RGB colour per building id (golden-ratio hues), (M, 3) uint8."""
    hue = (np.asarray(building_ids, dtype=float) * 0.618033988749895) % 1.0
    hsv = np.stack([hue * 179, np.full_like(hue, 200), np.full_like(hue, 255)], axis=-1).astype(np.uint8)
    rgb: np.ndarray = cv2.cvtColor(hsv[None], cv2.COLOR_HSV2RGB)[0]
    return rgb


def identity_overlay_png(photo_path: Path, labels: ReferenceLabelArrays) -> bytes:
    """PNG of the photo (at the labels' working size) with building pixels tinted by their building.

    Each pixel takes its most probable building's colour; the tint's strength is that building's
    probability in the column.
    """
    width = labels.width
    mask = labels.mask()
    image = ImageOps.exif_transpose(Image.open(photo_path)).convert("RGB").resize((width, mask.shape[0]))
    rgb = np.asarray(image).astype(float)
    prob = labels.column_prob
    out = rgb * 0.55  # darken what is not identified
    if prob.shape[1]:
        best = prob.argmax(axis=1)
        strength = prob[np.arange(width), best][None, :, None]
        tint = building_colors(labels.building_ids)[best][None, :, :].astype(float)
        blended = rgb * (1 - 0.6 * strength) + tint * 0.6 * strength
        out = np.where(mask[:, :, None], blended, out)
    ok, png = cv2.imencode(".png", cv2.cvtColor(out.clip(0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
    return png.tobytes()
