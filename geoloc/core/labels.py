"""Semantic classes used throughout (the paper's five plus 'other').

Segmentation outputs, simulator ground truth and evaluation all use these integer codes.
"""

from __future__ import annotations

import numpy as np

OTHER = 0
BUILDING = 1
TREE = 2
ROAD = 3
SKY = 4
CAR = 5

CLASS_NAMES: tuple[str, ...] = ("other", "building", "tree", "road", "sky", "car")

# RGB colours for overlays, indexed by class code.
CLASS_COLORS = np.array(
    [
        [0, 0, 0],
        [200, 70, 70],
        [60, 160, 60],
        [128, 64, 128],
        [110, 170, 230],
        [230, 200, 40],
    ],
    dtype=np.uint8,
)


def colorize(labels: np.ndarray) -> np.ndarray:
    """(H, W) class codes -> (H, W, 3) uint8 RGB."""
    rgb: np.ndarray = CLASS_COLORS[np.clip(labels, 0, len(CLASS_NAMES) - 1)]
    return rgb
