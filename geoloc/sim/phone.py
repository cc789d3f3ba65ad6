"""A walk world's photos as a phone writes them: GPS, compass and capture time, in EXIF and in the manifest.

The noise itself is drawn by :mod:`geoloc.sim.walks`; here it becomes what the photo carries (EXIF
GPS with the noise added, GPSImgDirection with ref "T", DateTimeOriginal + SubSecTimeOriginal,
GPSHPositioningError, and a Mapillary-style JSON in ImageDescription with the compass's stated
accuracy) and what the manifest records of it (every truth and every noise).
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

import numpy as np

from geoloc.sim.pose import Pose
from geoloc.sim.scene import Scene
from geoloc.sim.walks import GPS_CORRELATION_M, Shot, Walk, mapillary_description, query_compass


def walk_photo(scene: Scene, shot: Shot, walk: Walk) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """A walk photo's GPS record, its extra EXIF fields and its extra manifest fields (every truth and noise)."""
    pose = shot.pose
    dx = shot.gps_offset_m[0] + shot.gps_jump_m[0]
    dy = shot.gps_offset_m[1] + shot.gps_jump_m[1]
    lat, lon = scene.map.frame.to_wgs84(pose.x_m + dx, pose.y_m + dy)
    gps = {
        "lat": float(lat),
        "lon": float(lon),
        "noise_east_m": float(dx),
        "noise_north_m": float(dy),
        "noise_std_m": walk.gps_std_m,
        "model": "walk_ar1",
        "offset_east_m": shot.gps_offset_m[0],
        "offset_north_m": shot.gps_offset_m[1],
        "jump_east_m": shot.gps_jump_m[0],
        "jump_north_m": shot.gps_jump_m[1],
        "correlation_m": GPS_CORRELATION_M,
        "stated_accuracy_m": walk.gps_accuracy_m,
    }
    compass = _compass_record(
        scene, pose, shot.compass_error_deg, shot.compass_outlier, walk.compass_std_deg, walk.compass_accuracy_deg
    )
    heading = None if compass is None else compass["heading_deg"]
    extra = {
        "taken": shot.capture_time.replace(microsecond=0),
        "subsec_time": f"{shot.capture_time.microsecond // 1000:03d}",
        "heading_deg": heading,
        "gps_accuracy_m": walk.gps_accuracy_m,
        "description": mapillary_description(
            heading, walk.compass_accuracy_deg, shot.capture_time, walk.sequence_uuid, walk.gps_accuracy_m
        ),
    }
    phone = {
        "walk": {
            "walk_id": shot.walk_id,
            "index": shot.index,
            "sequence_uuid": walk.sequence_uuid,
            "heading_mode": shot.heading_mode,
        },
        "compass": compass,
        "capture_time": shot.capture_time.isoformat(timespec="milliseconds"),
    }
    return gps, extra, phone


def _compass_record(
    scene: Scene, pose: Pose, error_deg: float | None, outlier: bool, std_deg: float, accuracy_deg: float
) -> dict[str, Any] | None:
    """What the compass wrote (true-north heading, deg) and its noise; None when the photo has no compass."""
    if error_deg is None:
        return None
    true_heading = float(scene.map.frame.bearing_to_heading(pose.yaw_deg, pose.x_m, pose.y_m))
    return {
        "heading_deg": round((true_heading + error_deg) % 360.0, 3),
        "error_deg": error_deg,
        "outlier": outlier,
        "std_deg": round(std_deg, 4),
        "stated_accuracy_deg": accuracy_deg,
    }


def query_photo(
    scene: Scene, pose: Pose, rng: np.random.Generator, taken: datetime
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A walk world's query: its extra EXIF fields (a compass on some) and manifest fields."""
    err, outlier, std, stated = query_compass(rng)
    compass = _compass_record(scene, pose, None if err is None else round(err, 3), outlier, std, stated)
    heading = None if compass is None else compass["heading_deg"]
    extra = {
        "heading_deg": heading,
        "description": mapillary_description(heading, stated, taken, None, None),
    }
    return extra, {"compass": compass, "capture_time": taken.isoformat(timespec="milliseconds")}
