"""``geoloc eval photos``: real geo-tagged photos labelled on a map as the service labels references."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.core.context import MethodContext
from geoloc.core.geo import angle_difference_deg
from geoloc.evaluation.summaries import mean_or_none
from geoloc.evaluation.walks import compass_prior_at, place_photo_walks
from geoloc.localize.reference import LabelledReference, label_reference_photo
from geoloc.maps import load_map
from geoloc.photos.photo import Photo, load_photo


def evaluate_photos(
    photos_dir: str | Path,
    map_path: str | Path,
    truth_csv: str | Path | None = None,
    *,
    compass_prior: bool = False,
    place_walks: bool = False,
    context: MethodContext,
) -> dict[str, Any]:
    """Label real geo-tagged photos on a map with their EXIF GPS (the service's reference labelling).

    compass_prior: weight the headings with the photo's compass (``Photo.capture.compass``) as the robust
    prior the service uses (:func:`geoloc.evaluation.walks.compass_prior_at`); off by default,
    the map alone (as before). place_walks: then place the photos' walks jointly as the workers' sequence job
    does (:func:`geoloc.evaluation.walks.place_photo_walks`; the service's labelling is both options).
    context: the models and threads the labelling runs with.

    truth_csv: optional CSV with ``name`` and ``true_heading_deg`` columns (e.g. the phone's compass). Returns
    per photo the estimated compass heading and position, how far labelling moved it from the GPS tag,
    the buildings named, and the heading error against the truth.
    """
    city = load_map(map_path)
    truth: dict[str, dict[str, str]] = {}
    if truth_csv is not None:
        with open(truth_csv, newline="") as handle:
            truth = {row["name"]: row for row in csv.DictReader(handle)}
    photos: dict[str, Photo] = {}
    labelled: dict[str, LabelledReference] = {}
    for path in sorted(Path(photos_dir).iterdir()):
        if path.suffix.lower() not in (".jpg", ".jpeg", ".png"):
            continue
        photo = load_photo(path)
        if photo.gps is None:
            continue
        gps_x, gps_y = (float(v) for v in city.frame.to_local(*photo.gps))
        prior = compass_prior_at(photo, city, (gps_x, gps_y)) if compass_prior else None
        labelled[path.name] = label_reference_photo(city, photo, (gps_x, gps_y), heading_prior=prior, context=context)
        photos[path.name] = photo
    walks = place_photo_walks(city, photos, labelled) if place_walks else []
    rows = []
    for name, photo in photos.items():
        assert photo.gps is not None
        gps_x, gps_y = (float(v) for v in city.frame.to_local(*photo.gps))
        label = labelled[name].label
        heading = float(city.frame.bearing_to_heading(label.yaw_deg, label.x_m, label.y_m)) % 360.0
        lat, lon = (float(v) for v in city.frame.to_wgs84(label.x_m, label.y_m))
        names = []
        for entry in labelled[name].identity.building_extents():
            building = city.buildings[entry["building_id"]]
            names.append(building.name or building.osm_id)
        row: dict[str, Any] = {
            "name": name,
            "heading_deg": round(heading, 2),
            "lat": round(lat, 7),
            "lon": round(lon, 7),
            "moved_m": round(math.hypot(label.x_m - gps_x, label.y_m - gps_y), 2),
            "buildings": names,
            "vanishing_point_bins": label.vp_bins,
        }
        if name in truth:
            compass = float(truth[name]["true_heading_deg"])
            row["compass_heading_deg"] = compass
            row["heading_error_deg"] = round(angle_difference_deg(heading, compass), 2)
        rows.append(row)
    errors = [r["heading_error_deg"] for r in rows if "heading_error_deg" in r]
    return {
        "map": str(map_path),
        "photos_dir": str(photos_dir),
        "photos": rows,
        "heading_within_10deg": mean_or_none([float(e <= 10.0) for e in errors]),
        "heading_error_median_deg": round(float(np.median(errors)), 2) if errors else None,
        "walks": [len(walk.references) for walk in walks],
    }
