"""Pinhole camera: intrinsics, pixel columns <-> viewing angles, facade orientation conventions.

Frames and conventions (used by every module):

- Camera frame: x right, y down, z forward (the optical axis). The camera is upright (no
  significant roll); small pitch is corrected before these formulas are applied.
- A *column angle* ``alpha_deg`` is the horizontal angle of a viewing ray from the optical axis,
  positive to the right (clockwise seen from above), ``alpha = atan((x - cx) / f)``.
- A *bearing* in the local map frame is clockwise from local north (the +y "north" axis), in
  degrees. A camera with yaw ``yaw_deg`` sees column angle ``alpha`` along bearing
  ``yaw_deg + alpha``.
- A facade's *orientation relative to the camera* ``theta_deg`` is the bearing of the facade's
  outward normal minus the camera yaw, taken modulo 180 into [-90, 90). A wall seen head-on has
  theta = 0; a wall seen edge-on (parallel to the optical axis) has theta = -90. The sign is kept
  (the likelihood compares ``|cos(theta - theta_hat)|``, so only the value modulo 180 matters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_HFOV_DEG = 60.0
"""Horizontal field of view assumed when a photo carries no usable focal length."""

FULL_FRAME_WIDTH_MM = 36.0


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of an image.

    width, height: image size in pixels; focal_px: focal length in pixels (square pixels);
    cx, cy: principal point in pixels; source: where the focal length came from
    (``exif_35mm``, ``exif_focal_sensor``, ``given`` or ``default_hfov``).
    """

    width: int
    height: int
    focal_px: float
    cx: float
    cy: float
    source: str = "given"

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float, source: str = "given") -> Intrinsics:
        """Intrinsics with the principal point at the image centre and the given horizontal FOV."""
        if not 1.0 < hfov_deg < 179.0:
            raise ValueError(f"horizontal field of view must be in (1, 179) degrees, got {hfov_deg}")
        focal_px = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, focal_px, width / 2.0, height / 2.0, source)

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view (degrees)."""
        return math.degrees(2.0 * math.atan2(self.width / 2.0, self.focal_px))

    @property
    def matrix(self) -> np.ndarray:
        """3x3 calibration matrix K."""
        return np.array([[self.focal_px, 0.0, self.cx], [0.0, self.focal_px, self.cy], [0.0, 0.0, 1.0]])

    def column_angle_deg(self, x: np.ndarray | float) -> np.ndarray:
        """Column angle (deg, right of the optical axis) of pixel column(s) ``x`` (pixel centres at x)."""
        return np.degrees(np.arctan((np.asarray(x, dtype=float) - self.cx) / self.focal_px))

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera for an image resized to ``width`` x ``height``."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(width, height, self.focal_px * sx, self.cx * sx, self.cy * sy, self.source)


def intrinsics_from_focal(
    width: int,
    height: int,
    focal_35mm: float | None = None,
    focal_mm: float | None = None,
    sensor_width_mm: float | None = None,
    default_hfov_deg: float = DEFAULT_HFOV_DEG,
) -> Intrinsics:
    """Intrinsics from EXIF-style focal information, falling back to a default field of view.

    ``focal_35mm`` (EXIF FocalLengthIn35mmFilm) is the 35 mm-equivalent focal length, defined on the
    diagonal; we apply it to the longer image side as phones and cameras do in practice
    (36 mm film width for a landscape frame). ``focal_mm`` with ``sensor_width_mm`` (the sensor's
    longer side) is used next. Otherwise ``default_hfov_deg``.
    """
    long_side = max(width, height)
    if focal_35mm and focal_35mm > 0:
        focal_px = focal_35mm / FULL_FRAME_WIDTH_MM * long_side
        return Intrinsics(width, height, focal_px, width / 2.0, height / 2.0, "exif_35mm")
    if focal_mm and focal_mm > 0 and sensor_width_mm and sensor_width_mm > 0:
        focal_px = focal_mm / sensor_width_mm * long_side
        return Intrinsics(width, height, focal_px, width / 2.0, height / 2.0, "exif_focal_sensor")
    return Intrinsics.from_hfov(width, height, default_hfov_deg, source="default_hfov")


def wrap_orientation_deg(theta_deg: np.ndarray | float) -> np.ndarray:
    """Wrap facade orientations (deg) modulo 180 into [-90, 90)."""
    return (np.asarray(theta_deg, dtype=float) + 90.0) % 180.0 - 90.0


def orientation_from_direction(direction_cam: np.ndarray) -> np.ndarray:
    """Facade orientation theta (deg) from the facade's horizontal direction(s) in the upright camera frame.

    ``direction_cam``: (..., 3) direction of the facade's horizontal lines (x right, y down, z forward),
    e.g. a horizontal vanishing direction K^-1 v. A facade whose outward normal is at relative
    bearing theta has along-wall direction (cos theta, 0, -sin theta) (up to sign), hence
    theta = atan2(-d_z, d_x) modulo 180.
    """
    d = np.asarray(direction_cam, dtype=float)
    return wrap_orientation_deg(np.degrees(np.arctan2(-d[..., 2], d[..., 0])))


def orientation_from_vanishing_column(x_vp: np.ndarray | float, intrinsics: Intrinsics) -> np.ndarray:
    """Facade orientation theta (deg) from the column ``x_vp`` of its horizontal vanishing point.

    For an upright camera a horizontal vanishing point at column x has direction (x - cx, 0, f).
    A vanishing point at infinity (``x_vp`` = +-inf) means a wall seen head-on (theta = 0).
    """
    dx = np.asarray(x_vp, dtype=float) - intrinsics.cx
    direction = np.stack([dx, np.zeros_like(dx), np.full_like(dx, intrinsics.focal_px)], axis=-1)
    finite = np.isfinite(dx)
    theta = orientation_from_direction(np.where(finite[..., None], direction, [1.0, 0.0, 0.0]))
    return np.where(finite, theta, 0.0)


def vanishing_column_of_orientation(theta_deg: np.ndarray | float, intrinsics: Intrinsics) -> np.ndarray:
    """Column of the horizontal vanishing point of a facade with orientation ``theta_deg``.

    Inverse of :func:`orientation_from_vanishing_column`: x = cx - f / tan(theta); +inf for theta = 0.
    """
    t = np.tan(np.radians(np.asarray(theta_deg, dtype=float)))
    with np.errstate(divide="ignore"):
        column: np.ndarray = intrinsics.cx - intrinsics.focal_px / t
    return column
