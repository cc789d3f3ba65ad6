"""Options of a simulated world (:func:`geoloc.sim.world.generate_world`) and the camera they give."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from geoloc.core.camera import Intrinsics

FULL_FRAME_WIDTH_MM = 36.0
PHONE_CROP_FACTOR = 7.0  # 35 mm-equivalent / physical focal length of a typical phone main camera


@dataclass
class WorldOptions:
    """Options of :func:`generate_world` (see ``geoloc sim world --help``)."""

    n_references: int = 60
    n_queries: int = 30
    seed: int = 1
    gps_noise_m: float = 5.0
    query_gps_noise_m: float = 20.0  # negative: queries carry no GPS
    width: int = 640
    height: int = 480
    hfov_deg: float = 60.0
    radius_m: float = 220.0  # 0: the whole map
    min_ref_spacing_m: float = 10.0
    pitch_std_deg: float = 1.0
    roll_std_deg: float = 0.3
    jpeg_quality: int = 90
    # "scattered": references one by one along the streets (geoloc.sim.sampling); "walk": on walks, with a
    # phone's correlated GPS, compass and capture times (geoloc.sim.walks). Recorded in the manifest's
    # options only when not "scattered", so that scattered worlds stay byte-identical to those made before.
    capture: Literal["scattered", "walk"] = "scattered"
    # Query tracks (geoloc.sim.tracks): walks of query photos 3-8 m apart. Recorded in the manifest's options
    # only when there are tracks (the same reason as ``capture``).
    query_tracks: int = 0
    track_length: int = 10
    # The world disk's centre (WGS84 latitude, longitude in degrees); None: the buildings' median
    # (geoloc.sim.sampling.world_centre). Recorded in the manifest's options only when set (the same reason).
    centre_wgs84: tuple[float, float] | None = None


def camera_for(width: int, height: int, hfov_deg: float) -> tuple[Intrinsics, int, float]:
    """Intrinsics whose focal length is an integer 35 mm equivalent (as EXIF stores it).

    Returns (intrinsics, focal_35mm, focal_mm); the field of view is the nearest one to ``hfov_deg``
    that an integer FocalLengthIn35mmFilm gives on the image's longer side.
    """
    long_side = max(width, height)
    f35_exact = FULL_FRAME_WIDTH_MM / 2.0 / math.tan(math.radians(hfov_deg) / 2.0) * long_side / width
    f35 = max(1, int(round(f35_exact)))
    focal_px = f35 / FULL_FRAME_WIDTH_MM * long_side
    intr = Intrinsics(width, height, focal_px, width / 2.0, height / 2.0, "exif_35mm")
    return intr, f35, round(f35 / PHONE_CROP_FACTOR, 2)
