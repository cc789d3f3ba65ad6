"""Hand-made maps whose answers are known by construction (local metres, x east, y north)."""

from __future__ import annotations

import numpy as np

from geoloc.maps import CityMap, city_map_from_footprints


def box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def square_building() -> CityMap:
    """One 20 m x 20 m building centred on the origin, 15 m tall."""
    return city_map_from_footprints([box(-10, -10, 10, 10)], heights_m=[15.0], names=["Square"])


def l_shaped_building() -> CityMap:
    """An L: a 50 m x 10 m bar along x (y in 0..10) plus a 10 m x 30 m bar along y (x in 0..10)."""
    return city_map_from_footprints([L_RING], heights_m=[12.0])


def street_canyon() -> CityMap:
    """A north-south street 20 m wide (x in -10..10) lined by three distinct blocks on each side."""
    blocks = []
    for y0 in (-60.0, -20.0, 20.0):
        blocks.append(box(-40, y0, -10, y0 + 35))  # west side
        blocks.append(box(10, y0, 40, y0 + 35))  # east side
    return city_map_from_footprints(blocks, heights_m=[18.0] * len(blocks))


# Arms of different lengths (50 m east, 30 m north), so the L has no mirror symmetry either.
L_RING = np.array([[0, 0], [50, 0], [50, 10], [10, 10], [10, 30], [0, 30]], dtype=float)


def twin_buildings() -> CityMap:
    """Two identical L-shaped buildings 200 m apart (West at x -100..-50, East at x 100..150).

    An L has no rotational symmetry, so each view of one building is unique to it up to the twin:
    geometry alone cannot tell the twins apart, identities can.
    """
    return city_map_from_footprints([L_RING + (-100.0, 0.0), L_RING + (100.0, 0.0)], names=["West", "East"])
