"""The static scene of a simulated world: map, facade parametrisation, road raster, trees, cars, sky.

Everything here is in the map's local frame (x east, y north, metres) and is drawn once per
world from its seed, so every render of the world sees the same trees, cars, clouds and looks.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from geoloc.maps import CityMap
from geoloc.maps.raycast import FacadeIndex
from geoloc.sim.looks import BuildingLook, make_look
from geoloc.sim.sky_trees import cloud_panorama, tree_sprites

ROAD_HALF_WIDTH_M = 4.0
ROAD_RASTER_M = 0.25  # metres per road-raster cell
SIDEWALK_M = 3.5  # pavement along every facade, even where a street runs close
CAR_OFFSET_M = 3.0  # parked cars: centre this far from the street centreline
STREET_TREE_OFFSET_M = 5.6


@dataclass
class Trees:
    """Tree billboards: xy (T, 2) trunk positions, height_m (T,), crown_m (T,) crown width, sprite (T,) int."""

    xy: np.ndarray
    height_m: np.ndarray
    crown_m: np.ndarray
    sprite: np.ndarray


@dataclass
class Cars:
    """Parked cars: xy (C, 2) centres, direction (C, 2) unit along the car, rgb (C, 3) body colour in [0, 1]."""

    xy: np.ndarray
    direction: np.ndarray
    rgb: np.ndarray


@dataclass
class Sun:
    """Sun direction: azimuth (local bearing, deg) and elevation (deg)."""

    azimuth_deg: float
    elevation_deg: float

    @property
    def vector(self) -> np.ndarray:
        """Unit (east, north, up) vector towards the sun."""
        az, el = np.radians(self.azimuth_deg), np.radians(self.elevation_deg)
        return np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])


_CAR_COLOURS = np.array(
    [
        [0.92, 0.92, 0.92],
        [0.08, 0.08, 0.09],
        [0.62, 0.64, 0.66],
        [0.35, 0.36, 0.38],
        [0.12, 0.18, 0.40],
        [0.62, 0.08, 0.08],
        [0.85, 0.85, 0.80],
        [0.15, 0.30, 0.20],
        [0.70, 0.55, 0.30],
    ]
)


class Scene:
    """A map prepared for rendering (see module docstring).

    city_map: the loaded map. seed: world seed (looks, trees, cars, clouds, sun).
    street_trees_per_100m, cars_per_100m: densities along streets (both sides together).
    """

    def __init__(
        self,
        city_map: CityMap,
        seed: int = 0,
        *,
        street_trees_per_100m: float = 8.0,
        cars_per_100m: float = 8.0,
        cloud_cover: float | None = None,
    ) -> None:
        self.map = city_map
        self.seed = int(seed)
        self.index = FacadeIndex(city_map.facades)
        fac = city_map.facades
        n_b = len(city_map.buildings)
        # Along-perimeter offset of every facade start (facades of a building are consecutive).
        bid = fac.building_id.astype(np.int64)
        cum = np.cumsum(fac.length_m) - fac.length_m
        first = np.full(n_b, 0.0)
        starts = np.flatnonzero(np.r_[True, bid[1:] != bid[:-1]])
        first[bid[starts]] = cum[starts]
        self.facade_offset_m = (cum - first[bid]).astype(np.float64)
        self.perimeter_m = np.bincount(bid, weights=fac.length_m, minlength=n_b)
        self.facade_dir = (fac.end - fac.start) / fac.length_m[:, None]
        self._looks: dict[int, BuildingLook] = {}
        self._grown: dict[float, BaseGeometry] = {}
        rng = np.random.default_rng([self.seed, 1])
        self.sun = Sun(float(rng.uniform(0, 360)), float(rng.uniform(22, 50)))
        cover = float(rng.uniform(0.15, 0.6)) if cloud_cover is None else cloud_cover
        self.clouds = cloud_panorama(np.random.default_rng([self.seed, 2]), cover)
        self.sky_tint = rng.uniform(-0.04, 0.04, 3)
        self.tree_sprites = tree_sprites(np.random.default_rng([self.seed, 3]))
        self.ground_noise = _tile_noise(np.random.default_rng([self.seed, 4]), 256)
        self._build_road_raster()
        self.trees = self._place_trees(np.random.default_rng([self.seed, 5]), street_trees_per_100m)
        self.cars = self._place_cars(np.random.default_rng([self.seed, 6]), cars_per_100m)

    # -- looks ---------------------------------------------------------------------------------

    def look(self, building_id: int) -> BuildingLook:
        """The building's look, drawn on first use and cached."""
        look = self._looks.get(building_id)
        if look is None:
            mask = self.map.facades.building_id == building_id
            b = self.map.buildings[building_id]
            look = make_look(
                self.seed,
                building_id,
                float(b.height_m),
                float(self.perimeter_m[building_id]),
                self.facade_offset_m[mask],
                self.map.facades.length_m[mask],
                b.name,
            )
            self._looks[building_id] = look
        return look

    # -- ground ----------------------------------------------------------------------------------

    def _build_road_raster(self) -> None:
        """Rasterise streets (value 1 road, 2 kerb, 0 pavement) at ``ROAD_RASTER_M`` over the map."""
        x0, y0, x1, y1 = self.map.bounds_m
        pad = 150.0
        self.raster_origin = np.array([x0 - pad, y0 - pad])
        w = int(np.ceil((x1 - x0 + 2 * pad) / ROAD_RASTER_M))
        h = int(np.ceil((y1 - y0 + 2 * pad) / ROAD_RASTER_M))
        raster = np.zeros((h, w), np.uint8)
        polys = [self._to_raster(s) for s in self.map.streets if len(s) >= 2]
        if polys:
            thick = int(round(2 * ROAD_HALF_WIDTH_M / ROAD_RASTER_M))
            cv2.polylines(raster, polys, False, 1, thickness=thick, lineType=cv2.LINE_8)
            fac = self.map.facades
            seg = np.stack([fac.start, fac.end], axis=1)
            rings = list(np.round((seg - self.raster_origin) / ROAD_RASTER_M).astype(np.int32).reshape(-1, 2, 1, 2))
            cv2.polylines(raster, rings, False, 0, thickness=int(round(2 * SIDEWALK_M / ROAD_RASTER_M)))
        # Road fraction (0..255), slightly smoothed so that kerbs are straight lines at any distance.
        self.road = cv2.blur(raster * np.uint8(255), (3, 3))

    def _to_raster(self, xy: np.ndarray) -> np.ndarray:
        raster_xy: np.ndarray = np.round((xy - self.raster_origin) / ROAD_RASTER_M).astype(np.int32)
        return raster_xy.reshape(-1, 1, 2)

    def road_class(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) local points -> (N,) uint8: 1 road, 2 kerb, 0 pavement (also outside the raster).

        The road fraction is interpolated bilinearly between raster cells, so class boundaries are
        smooth curves rather than cell staircases.
        """
        g = (xy - self.raster_origin) / ROAD_RASTER_M - 0.5
        h, w = self.road.shape
        i0 = np.floor(g).astype(np.int64)
        a = (g - i0).astype(np.float32)
        x0 = np.clip(i0[:, 0], 0, w - 1)
        x1 = np.clip(i0[:, 0] + 1, 0, w - 1)
        y0 = np.clip(i0[:, 1], 0, h - 1)
        y1 = np.clip(i0[:, 1] + 1, 0, h - 1)
        r = self.road
        top = r[y0, x0] * (1 - a[:, 0]) + r[y0, x1] * a[:, 0]
        bot = r[y1, x0] * (1 - a[:, 0]) + r[y1, x1] * a[:, 0]
        frac = top * (1 - a[:, 1]) + bot * a[:, 1]
        out = np.where(frac > 127.5, 1, np.where(frac > 60, 2, 0)).astype(np.uint8)
        inside = (g[:, 0] >= 0) & (g[:, 0] < w) & (g[:, 1] >= 0) & (g[:, 1] < h)
        return np.where(inside, out, 0).astype(np.uint8)

    # -- street furniture --------------------------------------------------------------------------

    def _street_samples(
        self, rng: np.random.Generator, per_100m: float, offset_m: float, street_frac: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Points at ``offset_m`` either side of a random fraction of streets: (N, 2) xy, (N, 2) street dir."""
        pts, dirs = [], []
        for line in self.map.streets:
            if len(line) < 2 or rng.random() > street_frac:
                continue
            seg = np.diff(line, axis=0)
            seg_len = np.hypot(seg[:, 0], seg[:, 1])
            total = seg_len.sum()
            if total < 15.0:
                continue
            n = rng.poisson(total * per_100m / 100.0)
            if n == 0:
                continue
            s = np.sort(rng.uniform(0, total, n))
            cum = np.r_[0.0, np.cumsum(seg_len)]
            k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
            d = seg[k] / np.maximum(seg_len[k], 1e-9)[:, None]
            p = line[k] + d * (s - cum[k])[:, None]
            side = rng.choice([-1.0, 1.0], n)[:, None]
            normal = np.column_stack([d[:, 1], -d[:, 0]])
            pts.append(p + side * offset_m * normal)
            dirs.append(d)
        if not pts:
            return np.zeros((0, 2)), np.zeros((0, 2))
        return np.concatenate(pts), np.concatenate(dirs)

    def _clear_of_buildings(self, xy: np.ndarray, margin_m: float) -> np.ndarray:
        if len(xy) == 0:
            return np.zeros(0, bool)
        grown = self._grown.get(margin_m)
        if grown is None:
            grown = self._grown[margin_m] = shapely.buffer(self.map.building_union, margin_m, quad_segs=2)
        return ~shapely.contains_xy(grown, xy[:, 0], xy[:, 1])

    def _place_trees(self, rng: np.random.Generator, per_100m: float) -> Trees:
        street_xy, _ = self._street_samples(rng, per_100m, STREET_TREE_OFFSET_M, 0.5)
        street_xy = street_xy[self.road_class(street_xy) == 0] if len(street_xy) else street_xy
        xy = np.concatenate([np.asarray(self.map.trees, float).reshape(-1, 2), street_xy])
        xy = xy[self._clear_of_buildings(xy, 2.5)]
        n = len(xy)
        height = rng.uniform(6.0, 13.0, n)
        crown = height * rng.uniform(0.45, 0.7, n)
        return Trees(xy, height, crown, rng.integers(0, len(self.tree_sprites), n))

    def _place_cars(self, rng: np.random.Generator, per_100m: float) -> Cars:
        xy, d = self._street_samples(rng, per_100m, CAR_OFFSET_M, 0.5)
        keep = self._clear_of_buildings(xy, 1.5)
        xy, d = xy[keep], d[keep]
        if len(xy) and len(self.trees.xy):
            from scipy.spatial import cKDTree

            near_tree = cKDTree(self.trees.xy).query(xy, distance_upper_bound=2.0)[0] < 2.0
            xy, d = xy[~near_tree], d[~near_tree]
        # Drop cars overlapping an earlier one (closer than a car length).
        if len(xy):
            from scipy.spatial import cKDTree

            pairs = cKDTree(xy).query_pairs(5.0, output_type="ndarray")
            drop = np.zeros(len(xy), bool)
            drop[pairs[:, 1]] = True
            xy, d = xy[~drop], d[~drop]
        rgb = _CAR_COLOURS[rng.integers(0, len(_CAR_COLOURS), len(xy))] * rng.uniform(0.9, 1.05, (len(xy), 1))
        return Cars(xy, d, np.clip(rgb, 0, 1))


def _tile_noise(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size) float32 periodic noise in about [-1, 1] (FFT), for ground materials."""
    f = np.hypot(np.fft.fftfreq(size)[:, None], np.fft.fftfreq(size)[None, :]) + 1e-3
    spec = (rng.standard_normal(f.shape) + 1j * rng.standard_normal(f.shape)) / f**0.9
    field = np.real(np.fft.ifft2(spec))
    noise: np.ndarray = ((field - field.mean()) / (3 * field.std())).astype(np.float32)
    return noise
