"""Checks of a query's GeoJSON answer against its JSON answer (shared by the API tests of both kinds of answer)."""

from __future__ import annotations

from typing import Any

import pytest
import shapely.geometry
from pyproj import Geod

from service.geojson import VIEW_CONE_LENGTH_M

WGS84 = Geod(ellps="WGS84")


def check_query_collection(collection: dict[str, Any], query: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """Assert that ``collection`` is the RFC 7946 form of the answered ``query`` (its JSON); features by type.

    Every geometry is valid for shapely; a pose point per ranked location at its lon/lat with its properties;
    a view cone per pose whose apex is the camera, whose far edge lies :data:`VIEW_CONE_LENGTH_M` away and
    spans the answer's field of view around the heading; a building per identified building that has a
    footprint on the map.
    """
    result = query["result"]
    assert collection["type"] == "FeatureCollection"
    assert collection["attribution"] == query["attribution"] and collection["query_id"] == query["id"]
    by_type: dict[str, list[dict[str, Any]]] = {"pose": [], "view_cone": [], "building": []}
    for feature in collection["features"]:
        assert feature["type"] == "Feature"
        geometry = shapely.geometry.shape(feature["geometry"])
        assert geometry.is_valid and not geometry.is_empty, feature
        by_type[feature["properties"]["feature_type"]].append(feature)
    locations = result["locations"]
    assert len(by_type["pose"]) == len(by_type["view_cone"]) == len(locations)
    fov = result["camera"]["hfov_deg"]
    for point, cone, location in zip(by_type["pose"], by_type["view_cone"], locations, strict=True):
        assert point["geometry"] == {"type": "Point", "coordinates": [location["lon"], location["lat"]]}
        for key in ("rank", "heading_deg", "probability", "uncertainty_radius_m", "source", "inliers"):
            assert point["properties"][key] == location[key], key
        ring = cone["geometry"]["coordinates"][0]
        assert cone["geometry"]["type"] == "Polygon" and ring[0] == ring[-1] == [location["lon"], location["lat"]]
        assert cone["properties"]["fov_deg"] == pytest.approx(fov)
        bearings, _, distances = WGS84.inv(
            [location["lon"]] * (len(ring) - 2),
            [location["lat"]] * (len(ring) - 2),
            [c[0] for c in ring[1:-1]],
            [c[1] for c in ring[1:-1]],
        )
        assert distances == pytest.approx([VIEW_CONE_LENGTH_M] * len(distances), abs=0.01)
        offsets = [((b - location["heading_deg"] + 180) % 360) - 180 for b in bearings]
        assert offsets[0] == pytest.approx(fov / 2, abs=5e-3) and offsets[-1] == pytest.approx(-fov / 2, abs=5e-3)
        assert shapely.geometry.LinearRing(ring).is_ccw  # RFC 7946's right-hand rule
    return by_type
