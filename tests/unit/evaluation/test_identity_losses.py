"""Where a query's building pixels go after the transfer (``query_identity_losses`` of ``geoloc eval world``)."""

from __future__ import annotations

import math

import numpy as np

from geoloc.evaluation.queries import IDENTITY_LOSS_PARTS, identity_losses
from geoloc.localize.identity import identity_accuracy


def test_every_building_pixel_lands_in_one_part() -> None:
    # Ten truth building pixels in one row: buildings 1 (columns 0-5) and 2 (6-9); column 10 is sky.
    truth = np.array([[1, 1, 1, 1, 1, 1, 2, 2, 2, 2, -1]])
    mask = np.array([[False, False, True, True, True, True, True, True, True, True, True]])
    # Columns 0-1 outside the mask, 2 without identity, 3 building 2 (shown elsewhere), 4 building 7 (not
    # shown), 5-8 right, 9 building 1 (shown), 10 is not a building pixel and does not count.
    predicted = np.array([[-1, -1, -1, 2, 7, 1, 2, 2, 2, 1, 3]])
    losses = identity_losses(predicted, truth, mask)
    assert set(losses) == set(IDENTITY_LOSS_PARTS)
    assert losses == {
        "outside_mask": 0.2,
        "no_identity": 0.1,
        "building_shown": 0.2,
        "building_not_shown": 0.1,
        "right": 0.4,
    }
    assert math.isclose(sum(losses.values()), 1.0)
    assert losses["right"] == identity_accuracy(predicted, truth)


def test_a_right_identity_outside_the_mask_counts_as_right() -> None:
    truth = np.array([[4, 4]])
    losses = identity_losses(np.array([[4, -1]]), truth, np.array([[False, False]]))
    assert losses["right"] == 0.5 and losses["outside_mask"] == 0.5


def test_no_building_in_the_truth_gives_no_figure() -> None:
    losses = identity_losses(np.full((2, 2), 3), np.full((2, 2), -1), np.ones((2, 2), bool))
    assert all(math.isnan(v) for v in losses.values())
