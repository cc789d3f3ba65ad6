"""Building identities in an image: per-column probabilities over map buildings.

Identities are horizontal: as in the paper, a building pixel takes the identity distribution of its
column (the building that covers the column). An :class:`IdentityMap` stores, for one image, the
building mask and a (W, M) table of column probabilities over M building ids; rows may sum to
less than 1 (the rest is "unknown").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypedDict

import numpy as np


class BuildingExtent(TypedDict):
    """A building seen in an image (:meth:`IdentityMap.building_extents`).

    building_id: map building id. pixel_share: share of the image's building pixels whose most probable
    identity it is. x_start, x_end: its first and last pixel column (inclusive). probability: its mean
    identity probability over those columns.
    """

    building_id: int
    pixel_share: float
    x_start: int
    x_end: int
    probability: float


@dataclass
class IdentityMap:
    """Per-column building-identity probabilities of one image.

    building_ids: (M,) map building ids the columns of ``column_prob`` refer to.
    column_prob: (W, M) probability that the building seen in pixel column x is building_ids[m].
    building_mask: (H, W) bool, the pixels that are building (from segmentation or ground truth).
    """

    building_ids: np.ndarray
    column_prob: np.ndarray
    building_mask: np.ndarray

    def __post_init__(self) -> None:
        """Coerce the arrays to their dtypes; ValueError if ``column_prob``'s shape does not fit."""
        self.building_ids = np.asarray(self.building_ids, dtype=np.int64)
        self.column_prob = np.asarray(self.column_prob, dtype=np.float32)
        if self.column_prob.shape != (self.building_mask.shape[1], len(self.building_ids)):
            raise ValueError("column_prob must be (image width, number of building ids)")

    @property
    def width(self) -> int:
        """Image width (px)."""
        return int(self.building_mask.shape[1])

    def column_best(self, min_probability: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Most probable building id per column (-1 where none reaches ``min_probability``) and its probability."""
        if len(self.building_ids) == 0:
            return np.full(self.width, -1), np.zeros(self.width)
        best = np.argmax(self.column_prob, axis=1)
        prob = self.column_prob[np.arange(self.width), best]
        ids = np.where(prob > min_probability, self.building_ids[best], -1)
        return ids, prob

    def pixel_ids(self, min_probability: float = 0.0) -> np.ndarray:
        """(H, W) most probable building id per building pixel, -1 elsewhere."""
        ids, _ = self.column_best(min_probability)
        return np.where(self.building_mask, ids[None, :], -1)

    def probabilities_at(self, xy: np.ndarray) -> np.ndarray:
        """(N, M) identity probabilities at pixel positions ``xy`` (N, 2); zero off building pixels."""
        x = np.clip(np.round(xy[:, 0]).astype(int), 0, self.width - 1)
        y = np.clip(np.round(xy[:, 1]).astype(int), 0, self.building_mask.shape[0] - 1)
        probabilities: np.ndarray = self.column_prob[x] * self.building_mask[y, x][:, None]
        return probabilities

    def building_extents(self, min_share: float = 0.02) -> list[BuildingExtent]:
        """The buildings seen: id, pixel share of the building pixels, column extent, mean probability.

        A building is listed when it is the most probable identity of at least ``min_share`` of the
        building pixels. Sorted by pixel share, largest first.
        """
        ids, prob = self.column_best()
        pixels_per_column = self.building_mask.sum(axis=0)
        total = max(int(pixels_per_column.sum()), 1)
        result: list[BuildingExtent] = []
        for building_id in np.unique(ids[ids >= 0]):
            columns = np.flatnonzero((ids == building_id) & (pixels_per_column > 0))
            share = pixels_per_column[columns].sum() / total
            if len(columns) == 0 or share < min_share:
                continue
            result.append(
                BuildingExtent(
                    building_id=int(building_id),
                    pixel_share=float(share),
                    x_start=int(columns.min()),
                    x_end=int(columns.max()),
                    probability=float(prob[columns].mean()),
                )
            )
        return sorted(result, key=lambda r: -r["pixel_share"])


def identity_accuracy(predicted: np.ndarray, truth: np.ndarray) -> float:
    """Share of ground-truth building pixels (truth >= 0) whose predicted building id is right.

    predicted, truth: (H, W) building ids, -1 for none. As in the paper, only ground-truth building
    pixels count; a pixel with no prediction counts as wrong.
    """
    on = truth >= 0
    return float(np.mean(predicted[on] == truth[on])) if on.any() else float("nan")
