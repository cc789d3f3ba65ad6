"""Facade distances from where buildings meet the ground (a cue the paper's likelihood does not use).

For an upright camera at height h above flat ground, a ground point seen at depression angle
``delta`` below the horizon lies at horizontal distance ``h / tan(delta)``. Where a building's lowest
pixel in a column sits directly on ground pixels (road or pavement), that pixel is the facade's base
line, so the column's facade distance follows from the camera height, the intrinsics and the camera's
pitch and roll (from the vertical vanishing point). Where the base is hidden (a car, a tree, the
image's bottom edge), the distance stays unknown.

The distance tells the wall in front from the wall behind in a street, which orientation and extent
cannot (both are seen head-on and fill the view).
"""

from __future__ import annotations

import numpy as np

from geoloc.core import labels as classes
from geoloc.core.camera import Intrinsics

DEFAULT_CAMERA_HEIGHT_M = 1.6
"""Height of a hand-held camera above the ground (m)."""
MIN_DEPRESSION_DEG = 0.5  # base lines nearer the horizon than this give distances too uncertain to use
GROUND_ROWS = 3  # ground pixels required directly under the base line


def facade_base_distances(
    labels: np.ndarray,
    intrinsics: Intrinsics,
    rotation_upright_from_cam: np.ndarray | None = None,
    camera_height_m: float = DEFAULT_CAMERA_HEIGHT_M,
    max_distance_m: float = 150.0,
) -> np.ndarray:
    """(W,) horizontal distance (m) of the facade in each pixel column, NaN where its base is not visible.

    labels: (H, W) class codes (``geoloc.core.labels``); intrinsics: of that image;
    rotation_upright_from_cam: (3, 3) camera -> upright frame (``VanishingPoints``), identity if None.
    The base line of a column is its lowest building pixel; it counts when the ``GROUND_ROWS`` pixels
    below it are road (our road class includes pavement).
    """
    lab = np.asarray(labels)
    height, width = lab.shape
    building = lab == classes.BUILDING
    rows = np.arange(height)[:, None]
    lowest = np.where(building.any(axis=0), np.max(np.where(building, rows, -1), axis=0), -1)  # (W,)
    below = lowest[None, :] + 1 + np.arange(GROUND_ROWS)[:, None]  # (G, W)
    inside = (lowest >= 0) & (below[-1] < height)
    ground = np.zeros(width, dtype=bool)
    cols = np.flatnonzero(inside)
    ground[cols] = np.all(lab[below[:, cols], cols[None, :]] == classes.ROAD, axis=0)

    x = np.arange(width) + 0.5
    y = lowest + 1.0  # the bottom edge of the lowest building pixel
    rays = np.stack(
        [(x - intrinsics.cx) / intrinsics.focal_px, (y - intrinsics.cy) / intrinsics.focal_px, np.ones(width)]
    )
    rotation = np.eye(3) if rotation_upright_from_cam is None else np.asarray(rotation_upright_from_cam)
    upright = rotation @ rays  # (3, W): x right, y down, z forward (horizontal)
    horizontal = np.hypot(upright[0], upright[2])
    tan_depression = upright[1] / horizontal
    ok = ground & (tan_depression > np.tan(np.radians(MIN_DEPRESSION_DEG)))
    distance = np.full(width, np.nan)
    distance[ok] = camera_height_m / tan_depression[ok]
    distance[distance > max_distance_m] = np.nan
    return distance


def facade_top_elevations(
    labels: np.ndarray,
    intrinsics: Intrinsics,
    rotation_upright_from_cam: np.ndarray | None = None,
    min_elevation_deg: float = 2.0,
) -> np.ndarray:
    """(W,) tangent of the elevation angle of the building's top edge in each column, NaN where it is not seen.

    The top edge of a column is its highest building pixel; it counts when the pixels just above it are sky
    (a roof line against the sky, not a tree or the image's top border). With the building's height H from
    the map, ``(H - camera height) / tan(elevation)`` is the facade's horizontal distance, a cue that does
    not need the facade's base to be visible (:func:`geoloc.localize.likelihood.pose_likelihood`, skyline term).
    """
    lab = np.asarray(labels)
    height, width = lab.shape
    building = lab == classes.BUILDING
    rows = np.arange(height)[:, None]
    highest = np.where(building.any(axis=0), np.min(np.where(building, rows, height), axis=0), -1)  # (W,)
    above = highest[None, :] - 1 - np.arange(GROUND_ROWS)[:, None]  # (G, W)
    inside = (highest >= 0) & (above[-1] >= 0)
    sky = np.zeros(width, dtype=bool)
    cols = np.flatnonzero(inside)
    sky[cols] = np.all(lab[above[:, cols], cols[None, :]] == classes.SKY, axis=0)
    x = np.arange(width) + 0.5
    y = highest.astype(float)  # the top edge of the highest building pixel
    rays = np.stack(
        [(x - intrinsics.cx) / intrinsics.focal_px, (y - intrinsics.cy) / intrinsics.focal_px, np.ones(width)]
    )
    rotation = np.eye(3) if rotation_upright_from_cam is None else np.asarray(rotation_upright_from_cam)
    upright = rotation @ rays
    tan_elevation = -upright[1] / np.hypot(upright[0], upright[2])
    ok = sky & (tan_elevation > np.tan(np.radians(min_elevation_deg)))
    return np.where(ok, tan_elevation, np.nan)
