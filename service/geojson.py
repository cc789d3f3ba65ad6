"""GIS-friendly answers: a query's answer and a map's references as GeoJSON FeatureCollections (RFC 7946).

``GET /v1/queries/{id}`` and ``GET /v1/maps/{id}/references`` answer GeoJSON (``application/geo+json``) when
asked by ``Accept: application/geo+json`` or ``?format=geojson`` (``?format=json`` wins over the header).
Coordinates are WGS84 ``[lon, lat]``; every collection carries the map's ``attribution`` as a foreign member,
with ``query_id``/``map_id`` and ``status``.

A query's collection, in this order:

- one ``Point`` per ranked pose (``feature_type: "pose"``; ``rank``, ``heading_deg``, ``uncertainty_radius_m``,
  ``probability``, ``source``, ``inliers`` as the JSON answer has them);
- one ``Polygon`` view cone per pose (``feature_type: "view_cone"``): the apex at the camera, opening the
  photo's horizontal field of view (``result.camera.hfov_deg``; a track's frame's ``hfov_deg``, or
  :data:`DEFAULT_FOV_DEG` when the frame has none), :data:`VIEW_CONE_LENGTH_M` long, its far edge an arc of
  :data:`CONE_ARC_POINTS` points;
- one feature per identified building (``feature_type: "building"``), its footprint from the map (a
  ``Polygon``, or a ``MultiPolygon`` where the map's footprint is one) with ``building_id``, ``osm_id``,
  ``name``, ``pixel_share`` and ``probability``.

Decision (a query without an answer): a queued, processing or failed query answers with the same status code
as its JSON (200) and a valid, empty FeatureCollection whose foreign members say ``status`` (and ``error``):
a GIS tool opens it without error and a script reads why it is empty.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import Query, Request
from pyproj import Geod

from contracts.api import QueryOut, ReferenceList, TrackOut

GEOJSON_MEDIA_TYPE = "application/geo+json"
VIEW_CONE_LENGTH_M = 50.0
"""How far a view cone reaches from the camera (m): a street's width and the facades across it."""
DEFAULT_FOV_DEG = 60.0
"""The cone's opening (deg) when the answer states no field of view."""
CONE_ARC_POINTS = 9
_GEOD = Geod(ellps="WGS84")

Feature = dict[str, Any]

GEOJSON_RESPONSE: dict[str, Any] = {
    GEOJSON_MEDIA_TYPE: {
        "schema": {
            "type": "object",
            "description": "A GeoJSON FeatureCollection (RFC 7946, WGS84 lon/lat) with the foreign member "
            "`attribution`; asked by `Accept: application/geo+json` or `?format=geojson`",
            "required": ["type", "features", "attribution"],
            "properties": {
                "type": {"const": "FeatureCollection"},
                "features": {"type": "array", "items": {"type": "object"}},
                "attribution": {"type": "string"},
            },
        }
    }
}
"""The alternative media type of a route's 200 answer, for its ``responses=`` (``content``)."""

GeoJsonFormat = Annotated[
    Literal["json", "geojson"] | None,
    Query(
        alias="format",
        description="`geojson`: the answer as a GeoJSON FeatureCollection, as with `Accept: application/geo+json`; "
        "`json` wins over the header",
    ),
]
"""The ``?format=`` query parameter of the routes that also answer GeoJSON."""


def wants_geojson(request: Request, format_name: str | None) -> bool:
    """Whether the client asked for GeoJSON: ``?format=geojson``, else an ``Accept`` naming geo+json."""
    if format_name is not None:
        return format_name == "geojson"
    return GEOJSON_MEDIA_TYPE in request.headers.get("accept", "").lower()


def view_cone(lat: float, lon: float, heading_deg: float, fov_deg: float, length_m: float) -> dict[str, Any]:
    """The GeoJSON Polygon of a view: apex at (lat, lon), ``fov_deg`` wide around ``heading_deg``, ``length_m``.

    The far edge's points are ``length_m`` from the apex along the WGS84 geodesics (pyproj), 8 decimals (1 mm).
    """
    # From the right edge to the left: the ring runs counterclockwise, as RFC 7946 asks of exterior rings.
    azimuths = [heading_deg + fov_deg / 2 - fov_deg * i / (CONE_ARC_POINTS - 1) for i in range(CONE_ARC_POINTS)]
    lons, lats, _ = _GEOD.fwd([lon] * CONE_ARC_POINTS, [lat] * CONE_ARC_POINTS, azimuths, [length_m] * CONE_ARC_POINTS)
    apex = [lon, lat]
    arc = [[round(float(x), 8), round(float(y), 8)] for x, y in zip(lons, lats, strict=True)]
    return {"type": "Polygon", "coordinates": [[apex, *arc, apex]]}


def pose_points(locations: list[dict[str, Any]]) -> list[Feature]:
    """One Point feature per ranked pose of an answer's ``locations`` (the JSON answer's fields as properties)."""
    keys = ("rank", "heading_deg", "probability", "uncertainty_radius_m", "source", "inliers")
    return [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [loc["lon"], loc["lat"]]},
            "properties": {"feature_type": "pose", **{k: loc[k] for k in keys if k in loc}},
        }
        for loc in locations
    ]


def query_collection(out: QueryOut, footprints: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """A query as a FeatureCollection: poses, view cones, identified buildings (``footprints`` by building id)."""
    collection: dict[str, Any] = {
        "type": "FeatureCollection",
        "features": [],
        "attribution": out.attribution,
        "query_id": out.id,
        "map_id": out.map_id,
        "status": out.status,
    }
    if out.result is None:
        if out.error is not None:
            collection["error"] = out.error
        return collection
    result = out.result
    fov_deg = result.camera.hfov_deg
    locations = [loc.model_dump(mode="json") for loc in result.locations]
    cones = [
        {
            "type": "Feature",
            "geometry": view_cone(loc.lat, loc.lon, loc.heading_deg, fov_deg, VIEW_CONE_LENGTH_M),
            "properties": {
                "feature_type": "view_cone",
                "rank": loc.rank,
                "heading_deg": loc.heading_deg,
                "fov_deg": fov_deg,
                "length_m": VIEW_CONE_LENGTH_M,
            },
        }
        for loc in result.locations
    ]
    buildings = [
        {
            "type": "Feature",
            "id": b.building_id,
            "geometry": footprints[b.building_id],
            "properties": {"feature_type": "building", **b.model_dump(mode="json", exclude={"x_start", "x_end"})},
        }
        for b in result.buildings
        if b.building_id in footprints
    ]
    collection["features"] = [*pose_points(locations), *cones, *buildings]
    return collection


def references_collection(page: ReferenceList) -> dict[str, Any]:
    """A page of a map's references as Point features at their poses.

    The point is the pose labelling estimated when it found one (``pose_source: "estimated"``), else the
    uploaded position (``"exif"`` or ``"request"``); ``heading_deg`` likewise the estimated heading, else the
    prior. Paging as in JSON: ``next_after_id`` is a foreign member.
    """
    features = []
    for ref in page.references:
        est = ref.estimated
        if est is not None and est.lat is not None and est.lon is not None:
            lat, lon, pose_source = est.lat, est.lon, "estimated"
        else:
            lat, lon, pose_source = ref.position.lat, ref.position.lon, ref.position.source
        heading = est.heading_deg if est is not None and est.heading_deg is not None else ref.prior_heading_deg
        features.append(
            {
                "type": "Feature",
                "id": ref.id,
                "geometry": {"type": "Point", "coordinates": [lon, lat]},
                "properties": {
                    "feature_type": "reference",
                    "reference_id": ref.id,
                    "status": ref.status,
                    "pose_source": pose_source,
                    "heading_deg": heading,
                    "position": ref.position.model_dump(mode="json"),
                    "original_filename": ref.original_filename,
                    "buildings_seen": [b.building_id for b in ref.buildings_seen or []],
                },
            }
        )
    return {
        "type": "FeatureCollection",
        "features": features,
        "attribution": page.attribution,
        "map_id": page.map_id,
        "total": page.total,
        "next_after_id": page.next_after_id,
    }


def track_collection(out: TrackOut) -> dict[str, Any]:
    """A track as a FeatureCollection: its trajectory, a Point and a view cone per located frame.

    The trajectory is one ``LineString`` (``feature_type: "trajectory"``) through the located frames in order
    (absent with fewer than two); each frame is a ``Point`` (``feature_type: "frame"``: ``index``, ``query_id``,
    ``heading_deg``, ``uncertainty_radius_m``, ``source``, ``outlier``) and a ``Polygon`` view cone
    (``feature_type: "view_cone"``, as a query's). Foreign members: ``attribution``, ``track_id``, ``map_id``,
    ``status`` (and ``error``).
    """
    collection: dict[str, Any] = {
        "type": "FeatureCollection",
        "features": [],
        "attribution": out.attribution,
        "track_id": out.id,
        "map_id": out.map_id,
        "status": out.status,
    }
    if out.error is not None:
        collection["error"] = out.error
    located = [f for f in out.frames if f.lat is not None and f.lon is not None and f.heading_deg is not None]
    features: list[Feature] = []
    if len(located) >= 2:
        line = [[f.lon, f.lat] for f in located]
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": line},
                "properties": {"feature_type": "trajectory", "frames": [f.index for f in located]},
            }
        )
    keys = ("index", "query_id", "heading_deg", "uncertainty_radius_m", "source", "outlier", "capture_time")
    for f in located:
        assert f.lat is not None and f.lon is not None and f.heading_deg is not None
        props = f.model_dump(mode="json")
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [f.lon, f.lat]},
                "properties": {"feature_type": "frame", **{k: props[k] for k in keys}},
            }
        )
        fov_deg = float(f.hfov_deg or DEFAULT_FOV_DEG)
        features.append(
            {
                "type": "Feature",
                "geometry": view_cone(f.lat, f.lon, f.heading_deg, fov_deg, VIEW_CONE_LENGTH_M),
                "properties": {"feature_type": "view_cone", "index": f.index, "fov_deg": fov_deg},
            }
        )
    collection["features"] = features
    return collection
