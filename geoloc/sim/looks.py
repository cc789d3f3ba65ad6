"""A building's procedural look for the simulator, drawn once from (world seed, building id).

Seeding the generator with (world seed, building id) makes the same building look the same from every
viewpoint. The look picks a style, wall and trim colours, bay width and storey heights, then draws the
tiles (:mod:`geoloc.sim.textures`), the sign strip (:mod:`geoloc.sim.signs`) and the stain and detail
fields, always in that order from the one generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoloc.sim.signs import sign_strip
from geoloc.sim.textures import (
    NOISE_TEXELS_PER_M,
    detail_field,
    ground_tiles,
    mip_pyramid,
    smooth_noise,
    window_tiles,
)

_WALL_PALETTE = np.array(
    [
        [0.86, 0.78, 0.58],  # ochre
        [0.90, 0.86, 0.76],  # cream
        [0.84, 0.66, 0.60],  # old pink
        [0.70, 0.70, 0.68],  # concrete grey
        [0.62, 0.34, 0.26],  # brick red
        [0.66, 0.72, 0.76],  # blue grey
        [0.93, 0.92, 0.89],  # white
        [0.78, 0.62, 0.40],  # sand brown
        [0.55, 0.60, 0.52],  # sage
        [0.45, 0.42, 0.40],  # dark granite
    ]
)


@dataclass
class BuildingLook:
    """Per-building appearance (see module docstring). Sizes in metres; textures as mip lists.

    tiles[l]: (K, th, tw, 3) upper-floor bay tiles; ground[l]: (G, gh, tw, 3) ground-floor bay tiles
    (variant 0 shop front, 1 door, 2 small window); sign[l]: (sh, sw, 3) strip along the perimeter
    (u in metres from the ring start) covering ``SIGN_BAND_M``; sign_mask: (sw,) bool at level 0,
    True where a sign is; stain: (nh, nw) float32 multiplicative brightness at ``NOISE_TEXELS_PER_M``.
    """

    wall_rgb: np.ndarray
    trim_rgb: np.ndarray
    bay_m: float
    floor_m: float
    ground_m: float
    n_floors: int
    style: str
    shops: bool
    tiles: list[np.ndarray]
    ground: list[np.ndarray]
    sign: list[np.ndarray]
    sign_mask: np.ndarray
    stain: np.ndarray
    detail: np.ndarray


def make_look(
    seed: int,
    building_id: int,
    height_m: float,
    perimeter_m: float,
    facade_offsets_m: np.ndarray,
    facade_lengths_m: np.ndarray,
    name: str | None = None,
) -> BuildingLook:
    """Draw one building's look from a generator seeded with (``seed``, ``building_id``).

    facade_offsets_m, facade_lengths_m: (F_b,) the building's facades along its perimeter, used to
    centre signs on walls.
    """
    rng = np.random.default_rng([seed, building_id, 7])
    style = str(rng.choice(["plaster", "plaster", "brick", "stone", "modern"]))
    wall = _WALL_PALETTE[rng.integers(len(_WALL_PALETTE))].copy()
    if style == "brick":
        wall = np.array([0.58, 0.30, 0.22]) + rng.normal(0, 0.04, 3)
    if style == "modern":
        wall = np.array([0.55, 0.57, 0.58]) + rng.normal(0, 0.08, 3)
    wall = np.clip(wall * rng.uniform(0.85, 1.05) + rng.normal(0, 0.03, 3), 0.08, 0.97)
    trim = np.clip(wall * rng.uniform(0.6, 0.8) if rng.random() < 0.5 else wall * 0.4 + 0.55, 0.05, 0.98)
    ground_m = float(rng.uniform(3.9, 4.6)) if height_m > 7 else min(3.0, height_m)
    shops = bool(height_m > 7 and rng.random() < 0.75)
    n_floors = max(1, int(round((height_m - ground_m - 0.8) / rng.uniform(3.0, 3.5))))
    floor_m = max(2.6, (height_m - ground_m - 0.8) / n_floors) if height_m > ground_m + 2.6 else 3.0
    bay_m = float(rng.uniform(2.6, 4.2)) if style != "modern" else float(rng.uniform(1.5, 2.5))

    tiles = window_tiles(rng, style, wall, trim, bay_m, floor_m)
    ground = ground_tiles(rng, style, wall, trim, bay_m, ground_m, shops)
    sign, sign_mask = sign_strip(rng, wall, perimeter_m, facade_offsets_m, facade_lengths_m, shops, name)
    nh = max(2, int(np.ceil(height_m * NOISE_TEXELS_PER_M)) + 2)
    nw = max(2, int(np.ceil(perimeter_m * NOISE_TEXELS_PER_M)) + 2)
    stain = 1.0 + 0.07 * smooth_noise(rng, (nh, nw), 6.0) + 0.035 * smooth_noise(rng, (nh, nw), 1.5, 1)
    streaks = smooth_noise(rng, (1, nw), 1.2, 1)[0]
    stain -= 0.05 * np.clip(streaks, 0, None)[None, :] * np.linspace(1.0, 0.2, nh)[:, None]
    detail = detail_field(rng, perimeter_m, facade_offsets_m, facade_lengths_m)
    return BuildingLook(
        wall,
        trim,
        bay_m,
        floor_m,
        ground_m,
        n_floors,
        style,
        shops,
        mip_pyramid(tiles),
        mip_pyramid(ground),
        mip_pyramid(sign),
        sign_mask,
        stain.astype(np.float32),
        detail,
    )
