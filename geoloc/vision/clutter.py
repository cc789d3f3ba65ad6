"""Clutter filtering: line segments on trees, cars and sky are left out of vanishing point estimation.

Foliage gives random short lines and cars strong lines of their own orientation; neither says
anything about the facades' directions.
"""

from __future__ import annotations

import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.core.labels import CAR, SKY, TREE
from geoloc.vision.lines import sample_points_along
from geoloc.vision.vanishing import VanishingPoints, estimate_vanishing_points

CLUTTER_CLASSES: tuple[int, ...] = (TREE, CAR, SKY)
"""Classes whose segments are left out of vanishing point estimation."""


def segment_class_fraction(
    labels: np.ndarray, segments: np.ndarray, classes: tuple[int, ...], n_samples: int = 16
) -> np.ndarray:
    """(N,) share of points sampled along each segment whose label is one of ``classes``."""
    lab = np.asarray(labels)
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    if len(seg) == 0:
        return np.zeros(0)
    xi, yi = sample_points_along(seg, n_samples, lab.shape[1], lab.shape[0])
    return np.asarray(np.isin(lab[yi, xi], classes).mean(axis=1), dtype=float)


def estimate_scene_vanishing_points(
    labels: np.ndarray, segments: np.ndarray, intrinsics: Intrinsics, max_clutter_frac: float = 0.5
) -> VanishingPoints:
    """VPs from the segments that are not mostly on clutter (:data:`CLUTTER_CLASSES`).

    The returned ``assignment`` covers all input segments (-1 for the ones left out).
    """
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    use = segment_class_fraction(labels, seg, CLUTTER_CLASSES) <= max_clutter_frac
    vps = estimate_vanishing_points(seg[use], intrinsics)
    assignment = np.full(len(seg), -1)
    assignment[use] = vps.assignment
    vps.assignment = assignment
    return vps
