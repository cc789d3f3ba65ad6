"""Pose grids, the probability map over grid x yaws, the heatmap and the ranked poses.

A :class:`PoseGrid` is a regular grid of candidate camera positions in the local frame; cells
whose centre lies inside a building footprint are not candidates. The likelihood of all
candidates x yaws (:func:`geoloc.localize.likelihood.pose_likelihood`) becomes a posterior by
``posterior ∝ prior * likelihood ** sharpness`` normalised over grid x yaws. ``sharpness`` = 1
is the paper's plain normalisation; the likelihood is a similarity in [0, 1], not a calibrated
density, and plain normalisation lets the many mediocre yaws of a position outweigh one excellent
pose elsewhere, so the default sharpens it (``DEFAULT_SHARPNESS``). The heatmap is the posterior
summed over yaws. The top-N poses are the most probable positions (heatmap) picked greedily with a
minimum separation so that the N answers are distinct places; each carries the most probable yaw at
that position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoloc.maps import CityMap

DEFAULT_SHARPNESS = 8.0


@dataclass
class PoseGrid:
    """Candidate positions on a regular grid (local metres).

    origin_m: (x, y) of the centre of cell (row 0, col 0); rows go north (+y), columns east (+x).
    cell_m: spacing. shape: (rows, cols). valid: (rows, cols) bool, False inside buildings.
    """

    origin_m: tuple[float, float]
    cell_m: float
    shape: tuple[int, int]
    valid: np.ndarray

    @property
    def positions(self) -> np.ndarray:
        """(P, 2) centres of the valid cells, row-major order."""
        rows, cols = np.nonzero(self.valid)
        return np.column_stack([self.origin_m[0] + cols * self.cell_m, self.origin_m[1] + rows * self.cell_m])

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(min_x, min_y, max_x, max_y) of the grid's cell edges."""
        half = self.cell_m / 2.0
        x0, y0 = self.origin_m
        return (
            x0 - half,
            y0 - half,
            x0 + (self.shape[1] - 0.5) * self.cell_m,
            y0 + (self.shape[0] - 0.5) * self.cell_m,
        )

    def to_image(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Scatter per-valid-cell ``values`` (P,) into a (rows, cols) array."""
        out = np.full(self.shape, fill, dtype=float)
        out[self.valid] = values
        return out


def make_grid(
    city_map: CityMap,
    bounds_m: tuple[float, float, float, float],
    cell_m: float,
    exclude_inside: bool = True,
) -> PoseGrid:
    """A grid covering ``bounds_m`` = (min_x, min_y, max_x, max_y) with spacing ``cell_m``."""
    min_x, min_y, max_x, max_y = bounds_m
    cols = max(1, int(np.floor((max_x - min_x) / cell_m)) + 1)
    rows = max(1, int(np.floor((max_y - min_y) / cell_m)) + 1)
    grid = PoseGrid((min_x, min_y), cell_m, (rows, cols), np.ones((rows, cols), dtype=bool))
    if exclude_inside:
        grid.valid[:] = ~city_map.inside_buildings(grid.positions).reshape(rows, cols)
    return grid


def grid_around(
    city_map: CityMap, center_m: tuple[float, float], half_size_m: float, cell_m: float, exclude_inside: bool = True
) -> PoseGrid:
    """A square grid centred on ``center_m`` (its centre is a cell centre) reaching ``half_size_m`` each way."""
    n = int(np.floor(half_size_m / cell_m))
    cx, cy = center_m
    return make_grid(
        city_map, (cx - n * cell_m, cy - n * cell_m, cx + n * cell_m, cy + n * cell_m), cell_m, exclude_inside
    )


def sharpened_likelihood(likelihood: np.ndarray, sharpness: float = DEFAULT_SHARPNESS) -> np.ndarray | None:
    """``likelihood ** sharpness`` (float64, negatives clipped to 0), or None where that is zero for every pose.

    None means the map says nothing of the photo (no facade evidence: a wall filling the frame, open ground, or
    every value below the power's float range): the caller's priors alone must decide, not the first pose of a
    table of zeros.
    """
    weights = np.power(np.clip(likelihood, 0.0, None).astype(float), sharpness)
    return weights if weights.any() else None


def pose_posterior(
    likelihood: np.ndarray, prior: np.ndarray | None = None, sharpness: float = DEFAULT_SHARPNESS
) -> np.ndarray:
    """Normalise a (P, Y) likelihood (times an optional prior broadcastable to it) to sum to 1.

    An all-zero likelihood gives the (normalised) prior, or a uniform distribution.
    """
    sharpened = sharpened_likelihood(likelihood, sharpness)
    post = sharpened if sharpened is not None else np.ones(np.shape(likelihood))
    if prior is not None:
        post = post * np.broadcast_to(prior, post.shape)
    total = post.sum()
    if total <= 0:
        post = np.ones_like(post) if prior is None else np.broadcast_to(prior, post.shape).astype(float).copy()
        total = post.sum()
    normalised: np.ndarray = post / total
    return normalised


def position_heatmap(posterior: np.ndarray) -> np.ndarray:
    """(P, Y) posterior -> (P,) probability of each position (summed over yaws)."""
    heatmap: np.ndarray = posterior.sum(axis=1)
    return heatmap


@dataclass
class RankedPose:
    """One answer: a position (local m), the best yaw there (local bearing, deg) and probabilities."""

    rank: int
    x_m: float
    y_m: float
    yaw_deg: float
    probability: float  # of the position, summed over yaws
    pose_probability: float  # of this exact (position, yaw)
    likelihood: float = float("nan")  # p(I | pose) at this exact (position, yaw), when known


def top_poses(
    positions: np.ndarray,
    posterior: np.ndarray,
    yaws_deg: np.ndarray,
    n: int = 10,
    min_separation_m: float = 10.0,
    likelihood: np.ndarray | None = None,
) -> list[RankedPose]:
    """The ``n`` most probable positions, at least ``min_separation_m`` apart, with their best yaws.

    positions: (P, 2); posterior: (P, Y); yaws_deg: (Y,); likelihood: optional (P, Y) p(I | pose) reported
    with each pose.
    """
    heat = position_heatmap(posterior)
    remaining = heat.astype(float).copy()
    chosen: list[int] = []
    # Greedy non-maximum suppression: one vectorised pass per answer, not per grid cell.
    for _ in range(min(n, len(heat))):
        index = int(np.argmax(remaining))
        if remaining[index] < 0 or (chosen and heat[index] <= 0):
            break
        chosen.append(index)
        near = np.hypot(*(positions - positions[index]).T) < min_separation_m
        remaining[near] = -1.0
        remaining[index] = -1.0
    result = []
    for rank, index in enumerate(chosen, start=1):
        best_yaw = int(np.argmax(posterior[index]))
        result.append(
            RankedPose(
                rank,
                float(positions[index, 0]),
                float(positions[index, 1]),
                float(yaws_deg[best_yaw]),
                float(heat[index]),
                float(posterior[index, best_yaw]),
                float("nan") if likelihood is None else float(likelihood[index, best_yaw]),
            )
        )
    return result
