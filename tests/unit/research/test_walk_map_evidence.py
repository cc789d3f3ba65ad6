"""The walk-evidence diagnostic's boundary helpers: party walls from column ids, matching, the plainest detector."""

from __future__ import annotations

import math

import numpy as np

from research.walk_map_evidence import column_colour_boundaries, matched_share, party_walls


def test_party_walls_are_where_one_building_meets_another() -> None:
    ids = np.array([-1, -1, 3, 3, 3, 5, 5, -1, 7, 7, 2])
    # 3 | 5 and 7 | 2 are party walls; the edges against no building (-1) are not.
    assert party_walls(ids).tolist() == [4, 9]


def test_matched_share_counts_image_boundaries_with_a_map_boundary_within_a_degree() -> None:
    image = np.array([-10.0, 0.0, 12.0])
    assert matched_share(image, np.array([-9.2, 13.5])) == 1 / 3
    assert matched_share(image, np.array([])) == 0.0
    assert math.isnan(matched_share(np.array([]), np.array([1.0])))


def test_the_colour_detector_finds_a_wall_colour_change_and_not_a_plain_wall() -> None:
    height, width = 120, 200
    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[:, :90] = (200, 180, 120)  # ochre building
    rgb[:, 90:] = (110, 110, 115)  # grey building
    mask = np.zeros((height, width), bool)
    mask[20:, :] = True  # building below a strip of sky
    found = column_colour_boundaries(rgb, mask)
    assert len(found) == 1 and abs(int(found[0]) - 89) <= 1
    plain = np.full_like(rgb, 150)
    assert len(column_colour_boundaries(plain, mask)) == 0
    assert len(column_colour_boundaries(rgb, np.zeros_like(mask))) == 0  # no building: nothing to compare
