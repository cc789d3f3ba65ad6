"""WGS84 <-> local metric frame of a map, and compass heading <-> local bearing.

The only place that converts between geographic and local coordinates.

The local frame is an azimuthal equidistant projection centred on the map's origin (pyproj,
``always_xy=True``): x = east (m), y = north (m). Distances and bearings from the origin are exact;
within a few kilometres distortion is far below GPS error.

Bearings in the local frame are clockwise from the local +y axis ("grid north"). Grid north and
true north differ by the meridian convergence, which is zero at the origin and a few hundredths
of a degree across a city map; :meth:`LocalFrame.heading_to_bearing` applies it anyway so that the
conversion is exact and lives in one place.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pyproj import Transformer


def _fixed_pipeline(source: str, target: str) -> Transformer:
    """The transformer ``source`` -> ``target`` (``always_xy``) as the exact pipeline PROJ picks for it.

    pyproj keeps one PROJ object per thread and makes it on the thread's first call; for a transformer built
    with ``from_crs`` that is a PROJ database search (``proj_create_crs_to_crs``, 10 to 25 ms), paid again by
    every job (each runs on a new thread). Rebuilt from its pipeline string (``definition``, what PROJ
    executes), a thread's first call only parses the string (0.2 ms), with the same results bit for bit
    (checked in ``tests/test_geo.py`` on points near and far from the origin). The search runs once, here.
    """
    return Transformer.from_pipeline(Transformer.from_crs(source, target, always_xy=True).definition)


@dataclass(frozen=True)
class LocalFrame:
    """Local East-North metric frame centred at (``origin_lat``, ``origin_lon``) in degrees WGS84."""

    origin_lat: float
    origin_lon: float
    _forward: Transformer = field(init=False, repr=False, compare=False)
    _inverse: Transformer = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Check the origin (degrees) and build the pyproj transformers."""
        if not (-90.0 < self.origin_lat < 90.0 and -180.0 <= self.origin_lon <= 180.0):
            raise ValueError(f"invalid origin ({self.origin_lat}, {self.origin_lon})")
        object.__setattr__(self, "origin_lat", float(self.origin_lat))
        object.__setattr__(self, "origin_lon", float(self.origin_lon))
        definition = f"+proj=aeqd +lat_0={self.origin_lat!r} +lon_0={self.origin_lon!r} +ellps=WGS84 +units=m"
        object.__setattr__(self, "_forward", _fixed_pipeline("EPSG:4326", definition))
        object.__setattr__(self, "_inverse", _fixed_pipeline(definition, "EPSG:4326"))

    def to_local(self, lat: np.ndarray | float, lon: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 degrees -> (east_m, north_m)."""
        east, north = self._forward.transform(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float))
        return np.asarray(east), np.asarray(north)

    def to_wgs84(self, east_m: np.ndarray | float, north_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(east_m, north_m) -> WGS84 (lat, lon) in degrees."""
        lon, lat = self._inverse.transform(np.asarray(east_m, dtype=float), np.asarray(north_m, dtype=float))
        return np.asarray(lat), np.asarray(lon)

    def meridian_convergence_deg(self, east_m: np.ndarray | float, north_m: np.ndarray | float) -> np.ndarray:
        """Angle (deg) from grid north to true north at local points, clockwise positive.

        Computed numerically: the grid bearing of a 1 m step due true north.
        """
        lat, lon = self.to_wgs84(east_m, north_m)
        step_deg = 1.0 / 111_320.0
        e2, n2 = self.to_local(lat + step_deg, lon)
        convergence_deg: np.ndarray = np.degrees(
            np.arctan2(e2 - np.asarray(east_m, float), n2 - np.asarray(north_m, float))
        )
        return convergence_deg

    def heading_to_bearing(
        self, heading_deg: np.ndarray | float, east_m: np.ndarray | float = 0.0, north_m: np.ndarray | float = 0.0
    ) -> np.ndarray:
        """Compass heading (deg clockwise from true north) at a local point -> local bearing (deg, [0, 360))."""
        bearing: np.ndarray = (np.asarray(heading_deg, float) + self.meridian_convergence_deg(east_m, north_m)) % 360.0
        return bearing

    def bearing_to_heading(
        self, bearing_deg: np.ndarray | float, east_m: np.ndarray | float = 0.0, north_m: np.ndarray | float = 0.0
    ) -> np.ndarray:
        """Local bearing (deg) at a local point -> compass heading (deg clockwise from true north, [0, 360))."""
        heading: np.ndarray = (np.asarray(bearing_deg, float) - self.meridian_convergence_deg(east_m, north_m)) % 360.0
        return heading


def frame_for_bbox(min_lat: float, min_lon: float, max_lat: float, max_lon: float) -> LocalFrame:
    """The local frame centred on a bounding box (degrees)."""
    return LocalFrame((min_lat + max_lat) / 2.0, (min_lon + max_lon) / 2.0)


def bearing_deg(dx_east: np.ndarray | float, dy_north: np.ndarray | float) -> np.ndarray:
    """Bearing (deg clockwise from +y, [0, 360)) of a local displacement."""
    # Rounding first keeps -1e-14 from becoming 359.99999999999997 (360.0 once cast to float32).
    return np.round(np.degrees(np.arctan2(dx_east, dy_north)), 9) % 360.0


def bearing_vector(bearing_deg_: np.ndarray | float) -> np.ndarray:
    """Unit (east, north) vector(s) for bearing(s) in degrees; shape (..., 2)."""
    b = np.radians(np.asarray(bearing_deg_, dtype=float))
    return np.stack([np.sin(b), np.cos(b)], axis=-1)


def angle_difference_deg(a_deg: float, b_deg: float) -> float:
    """Absolute difference of two headings or bearings (deg), in [0, 180]."""
    return abs((a_deg - b_deg + 180.0) % 360.0 - 180.0)
