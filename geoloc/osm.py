"""Map loading: buildings and their facades from OpenStreetMap (.osm, .osm.bz2, .osm.pbf) or GeoJSON.

Entry point: :func:`load_map` (also ``geoloc map info FILE``). The format is recognised from the
file's content, not its name.

What counts as a building: OSM ways and ``type=multipolygon`` relations tagged ``building=*``
(not ``building=no``); ``building:part`` ways are counted but not used (parts overlap their
building). Relations contribute their outer rings minus inner rings; inner courtyards are
facades too. In GeoJSON, (Multi)Polygon features with a ``building`` property are buildings; if
no feature has one, every polygon feature is taken as a building.

Geometry problems are repaired or skipped and counted in :class:`LoadReport`, never raised:
unclosed ways are closed when the gap is under ``MAX_CLOSING_GAP_M`` (else skipped), rings with
fewer than 3 distinct points or an area under 1 m^2 are skipped, self-intersecting polygons are
repaired with shapely's ``make_valid``, node references missing from the extract are dropped.
A file that is not map data, or holds no buildings, raises :class:`MapLoadError`.

Building ids are stable for a given file: buildings are numbered 0..B-1 in order of
(OSM type, OSM id) (GeoJSON: feature order). Heights: OSM ``height`` (metres, units stripped),
else ``building:levels`` x 3 m, else ``DEFAULT_HEIGHT_M``.
"""

from __future__ import annotations

import bz2
import json
import math
import re
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Polygon, mapping
from shapely.geometry.polygon import orient
from shapely.ops import linemerge, polygonize, unary_union

from geoloc.geo import LocalFrame, bearing_deg, frame_for_bbox

DEFAULT_HEIGHT_M = 12.0
"""Height of a building with neither ``height`` nor ``building:levels`` (about four storeys)."""
LEVEL_HEIGHT_M = 3.0
MAX_CLOSING_GAP_M = 5.0
MIN_AREA_M2 = 1.0
MIN_FACADE_LENGTH_M = 0.1


class MapLoadError(ValueError):
    """The file is not map data we can read, or holds no buildings."""


@dataclass
class LoadReport:
    """Counts of what was read, repaired and skipped while loading a map."""

    format: str = ""
    building_ways: int = 0
    building_relations: int = 0
    building_parts_ignored: int = 0
    closed_unclosed_ways: int = 0
    skipped_unclosed: int = 0
    skipped_degenerate: int = 0
    repaired_invalid: int = 0
    skipped_incomplete_relations: int = 0
    missing_node_refs: int = 0
    short_facades_dropped: int = 0

    def as_dict(self) -> dict[str, int | str]:
        return asdict(self)


@dataclass
class Building:
    """One building. ``polygon`` is in the map's local frame (metres)."""

    building_id: int
    osm_id: str  # "way/123", "relation/45" or a GeoJSON feature id
    name: str | None
    height_m: float
    height_source: str  # "height", "levels" or "default"
    polygon: Polygon | MultiPolygon
    tags: dict[str, str] = field(default_factory=dict)


@dataclass
class Facades:
    """All facades (polygon edges) of a map as parallel arrays, local frame, metres.

    start, end: (F, 2) endpoints; the building lies to the left when walking start -> end
    (exterior rings counter-clockwise, courtyard rings clockwise).
    normal: (F, 2) unit outward normal (away from the building's material).
    normal_bearing_deg: (F,) bearing of the outward normal (deg clockwise from north).
    length_m: (F,); building_id: (F,) int32.
    """

    start: np.ndarray
    end: np.ndarray
    normal: np.ndarray
    normal_bearing_deg: np.ndarray
    length_m: np.ndarray
    building_id: np.ndarray

    def __len__(self) -> int:
        return len(self.length_m)


@dataclass
class CityMap:
    """A loaded map: its local frame, buildings, facades and street furniture (all local metres)."""

    frame: LocalFrame
    buildings: list[Building]
    facades: Facades
    building_height_m: np.ndarray  # (B,)
    trees: np.ndarray  # (T, 2) positions of natural=tree nodes
    streets: list[np.ndarray]  # polylines (N, 2) of highway centrelines
    bbox_wgs84: tuple[float, float, float, float]  # min_lat, min_lon, max_lat, max_lon
    report: LoadReport
    source: str = ""

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(min_x, min_y, max_x, max_y) of the buildings' footprints in the local frame."""
        pts = np.concatenate([self.facades.start, self.facades.end])
        return (*pts.min(axis=0), *pts.max(axis=0))

    @property
    def building_union(self) -> Polygon | MultiPolygon:
        """Union of all footprints (cached), for inside/outside tests."""
        if not hasattr(self, "_union"):
            self._union = unary_union([b.polygon for b in self.buildings])
        return self._union

    def inside_buildings(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) local points -> (N,) bool, True where a point lies inside a footprint."""
        return shapely.contains_xy(self.building_union, xy[:, 0], xy[:, 1])

    def contains_wgs84(self, lat: float, lon: float, margin_m: float = 0.0) -> bool:
        """Whether a WGS84 point lies within the map's bounding box grown by ``margin_m``."""
        x, y = self.frame.to_local(lat, lon)
        min_x, min_y, max_x, max_y = self.local_bbox_m
        return bool(min_x - margin_m <= x <= max_x + margin_m and min_y - margin_m <= y <= max_y + margin_m)

    @property
    def local_bbox_m(self) -> tuple[float, float, float, float]:
        """The WGS84 bounding box expressed in the local frame (min_x, min_y, max_x, max_y)."""
        min_lat, min_lon, max_lat, max_lon = self.bbox_wgs84
        xs, ys = self.frame.to_local(
            np.array([min_lat, min_lat, max_lat, max_lat]), np.array([min_lon, max_lon, min_lon, max_lon])
        )
        return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())


# ----------------------------------------------------------------------------------------------
# Public API


def load_map(path: str | Path) -> CityMap:
    """Load buildings, facades, trees and streets from an OSM (.osm/.osm.bz2/.osm.pbf) or GeoJSON file."""
    path = Path(path)
    if not path.is_file():
        raise MapLoadError(f"{path} is not a file")
    kind = _sniff_format(path)
    raw = _read_geojson(path) if kind == "geojson" else _read_osm(path, kind)
    return _build_city_map(raw, source=path.name)


def city_map_from_footprints(
    footprints_m: list[np.ndarray],
    heights_m: list[float] | None = None,
    names: list[str | None] | None = None,
    origin_wgs84: tuple[float, float] = (60.17, 24.94),
) -> CityMap:
    """A map made from footprints given in a local frame (hand-made test scenes, simulations).

    footprints_m: list of (N, 2) rings (x east, y north, metres; closed or not, any winding) in the
    frame centred at ``origin_wgs84`` (lat, lon). Building i gets id i and OSM id ``way/i+1``.
    """
    frame = LocalFrame(*origin_wgs84)
    raw_buildings = []
    for i, ring in enumerate(footprints_m):
        ring = np.asarray(ring, dtype=float)
        if not np.allclose(ring[0], ring[-1]):
            ring = np.vstack([ring, ring[:1]])
        lat, lon = frame.to_wgs84(ring[:, 0], ring[:, 1])
        tags = {"building": "yes"}
        if heights_m is not None:
            tags["height"] = str(heights_m[i])
        if names is not None and names[i]:
            tags["name"] = names[i]
        raw_buildings.append(_RawBuilding(f"way/{i + 1}", tags, [list(zip(lon, lat, strict=True))], []))
    return _build_city_map(_RawMap("footprints", raw_buildings, [], [], LoadReport("footprints")), "footprints", frame)


def map_summary(city_map: CityMap) -> dict:
    """A JSON-ready summary: counts, bounding box, named buildings, repair report."""
    named = [b for b in city_map.buildings if b.name]
    return {
        "source": city_map.source,
        "buildings": len(city_map.buildings),
        "facades": len(city_map.facades),
        "named_buildings": len(named),
        "named_examples": sorted({b.name for b in named})[:10],
        "trees": len(city_map.trees),
        "streets": len(city_map.streets),
        "bbox_wgs84": dict(zip(("min_lat", "min_lon", "max_lat", "max_lon"), city_map.bbox_wgs84, strict=True)),
        "origin_wgs84": {"lat": city_map.frame.origin_lat, "lon": city_map.frame.origin_lon},
        "extent_m": [round(v, 1) for v in city_map.bounds_m],
        "height_sources": dict(Counter(b.height_source for b in city_map.buildings)),
        "report": city_map.report.as_dict(),
    }


def buildings_geojson(city_map: CityMap) -> dict:
    """Buildings as a GeoJSON FeatureCollection in WGS84 (lon, lat)."""

    def to_wgs(geom: Polygon | MultiPolygon) -> dict:
        def transform(coords: np.ndarray) -> np.ndarray:
            lat, lon = city_map.frame.to_wgs84(coords[:, 0], coords[:, 1])
            return np.column_stack([lon, lat])

        return mapping(shapely.transform(geom, transform))

    features = [
        {
            "type": "Feature",
            "id": b.building_id,
            "geometry": to_wgs(b.polygon),
            "properties": {
                "building_id": b.building_id,
                "osm_id": b.osm_id,
                "name": b.name,
                "height_m": b.height_m,
                "height_source": b.height_source,
            },
        }
        for b in city_map.buildings
    ]
    return {"type": "FeatureCollection", "features": features}


# ----------------------------------------------------------------------------------------------
# Reading


@dataclass
class _RawBuilding:
    osm_id: str
    tags: dict[str, str]
    outers: list[list[tuple[float, float]]]  # rings as (lon, lat)
    inners: list[list[tuple[float, float]]]
    from_relation: bool = False


@dataclass
class _RawMap:
    format: str
    buildings: list[_RawBuilding]
    trees: list[tuple[float, float]]
    streets: list[list[tuple[float, float]]]
    report: LoadReport


def _sniff_format(path: Path) -> str:
    head = path.read_bytes()[:4096] if path.stat().st_size < 4096 else path.open("rb").read(4096)
    if head.startswith(b"BZh"):
        inner = bz2.BZ2File(path).read(512).lstrip()
        if inner.startswith(b"<"):
            return "osm.bz2"
        raise MapLoadError(f"{path.name}: a bz2 file that does not hold OSM XML")
    stripped = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if stripped.startswith(b"<"):
        if b"<osm" in head:
            return "osm"
        raise MapLoadError(f"{path.name}: XML but not OpenStreetMap data (no <osm> element)")
    if stripped.startswith(b"{"):
        return "geojson"
    if b"OSMHeader" in head[:64]:
        return "pbf"
    raise MapLoadError(f"{path.name}: not map data (expected OSM XML, .osm.bz2, .osm.pbf or GeoJSON)")


def _read_osm(path: Path, kind: str) -> _RawMap:
    import osmium

    report = LoadReport(format=kind)
    way_nodes: dict[int, list[tuple[float, float]]] = {}
    building_ways: list[tuple[int, dict[str, str]]] = []
    relations: list[tuple[int, dict[str, str], list[tuple[int, str]]]] = []
    trees: list[tuple[float, float]] = []
    streets: list[list[tuple[float, float]]] = []
    osmium_format = {"osm": "osm", "osm.bz2": "osm.bz2", "pbf": "pbf"}[kind]
    try:
        processor = osmium.FileProcessor(osmium.io.File(str(path), osmium_format)).with_locations()
        for obj in processor:
            if obj.is_node():
                if obj.tags.get("natural") == "tree" and obj.location.valid():
                    trees.append((obj.location.lon, obj.location.lat))
            elif obj.is_way():
                coords = []
                for node in obj.nodes:
                    if node.location.valid():
                        coords.append((node.location.lon, node.location.lat))
                    else:
                        report.missing_node_refs += 1
                way_nodes[obj.id] = coords
                tags = dict(obj.tags)
                if "building:part" in tags and "building" not in tags:
                    report.building_parts_ignored += 1
                elif tags.get("building", "no") != "no":
                    building_ways.append((obj.id, tags))
                elif "highway" in tags and len(coords) >= 2:
                    streets.append(coords)
            elif obj.is_relation():
                tags = dict(obj.tags)
                if tags.get("type") == "multipolygon" and tags.get("building", "no") != "no":
                    members = [(m.ref, m.role) for m in obj.members if m.type == "w"]
                    relations.append((obj.id, tags, members))
    except RuntimeError as exc:  # osmium's parse errors
        raise MapLoadError(f"{path.name}: cannot read OSM data: {exc}") from exc

    buildings: list[_RawBuilding] = []
    for way_id, tags in building_ways:
        report.building_ways += 1
        buildings.append(_RawBuilding(f"way/{way_id}", tags, [way_nodes.get(way_id, [])], []))
    for rel_id, tags, members in relations:
        report.building_relations += 1
        outers = [way_nodes[ref] for ref, role in members if role != "inner" and ref in way_nodes]
        inners = [way_nodes[ref] for ref, role in members if role == "inner" and ref in way_nodes]
        if len(outers) < sum(role != "inner" for _, role in members):
            report.skipped_incomplete_relations += 1
            continue
        buildings.append(_RawBuilding(f"relation/{rel_id}", tags, outers, inners, from_relation=True))
    return _RawMap(kind, buildings, trees, streets, report)


def _read_geojson(path: Path) -> _RawMap:
    report = LoadReport(format="geojson")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapLoadError(f"{path.name}: not valid GeoJSON: {exc}") from exc
    if not isinstance(data, dict):
        raise MapLoadError(f"{path.name}: GeoJSON must be an object")
    features = data.get("features") if data.get("type") == "FeatureCollection" else [data]
    if not isinstance(features, list):
        raise MapLoadError(f"{path.name}: GeoJSON FeatureCollection without a 'features' list")
    polygons = [
        f
        for f in features
        if isinstance(f, dict) and (f.get("geometry") or {}).get("type") in ("Polygon", "MultiPolygon")
    ]
    any_building_prop = any("building" in (f.get("properties") or {}) for f in polygons)
    buildings: list[_RawBuilding] = []
    for index, feature in enumerate(polygons):
        props = {str(k): str(v) for k, v in (feature.get("properties") or {}).items() if v is not None}
        if any_building_prop and props.get("building", "no") == "no":
            continue
        geometry = feature["geometry"]
        parts = geometry["coordinates"] if geometry["type"] == "MultiPolygon" else [geometry["coordinates"]]
        outers, inners = [], []
        try:
            for part in parts:
                rings = [[(float(p[0]), float(p[1])) for p in ring] for ring in part]
                # RFC 7946 rings repeat their first position; one that doesn't is closed implicitly.
                for ring in rings:
                    if len(ring) >= 3 and ring[0] != ring[-1]:
                        ring.append(ring[0])
                        report.closed_unclosed_ways += 1
                if rings:
                    outers.append(rings[0])
                    inners.extend(rings[1:])
        except (TypeError, IndexError, ValueError):
            report.skipped_degenerate += 1
            continue
        osm_id = str(feature.get("id") or props.get("@id") or props.get("osm_id") or f"feature/{index}")
        report.building_ways += 1
        buildings.append(_RawBuilding(osm_id, props, outers, inners, from_relation=len(parts) > 1))
    return _RawMap("geojson", buildings, [], [], report)


# ----------------------------------------------------------------------------------------------
# Geometry


def _parse_height(tags: dict[str, str]) -> tuple[float, str]:
    number = re.compile(r"^\s*([0-9]+(?:[.,][0-9]+)?)\s*(m|meters|metres)?\s*$")
    height = number.match(tags.get("height", ""))
    if height:
        value = float(height.group(1).replace(",", "."))
        if 1.0 <= value <= 500.0:
            return value, "height"
    levels = number.match(tags.get("building:levels", ""))
    if levels:
        value = float(levels.group(1).replace(",", "."))
        if 0.5 <= value <= 150.0:
            return value * LEVEL_HEIGHT_M, "levels"
    return DEFAULT_HEIGHT_M, "default"


def _ring_polygon(ring: np.ndarray, report: LoadReport, assemble_lines: bool = False) -> Polygon | None:
    """A closed, valid polygon from one ring of local coordinates, or None (counted) if unusable."""
    if len(ring) >= 2 and not np.allclose(ring[0], ring[-1]):
        gap = float(np.hypot(*(ring[0] - ring[-1])))
        if gap > MAX_CLOSING_GAP_M:
            report.skipped_unclosed += 1
            return None
        report.closed_unclosed_ways += 1
        ring = np.vstack([ring, ring[:1]])
    if len(np.unique(np.round(ring, 3), axis=0)) < 3:
        report.skipped_degenerate += 1
        return None
    return Polygon(ring)


def _relation_rings(rings: list[np.ndarray], report: LoadReport) -> list[Polygon]:
    """Join a relation's member ways into closed rings (they may be split across several ways)."""
    closed, open_lines = [], []
    for ring in rings:
        if len(ring) >= 4 and np.allclose(ring[0], ring[-1]):
            closed.append(Polygon(ring))
        elif len(ring) >= 2:
            open_lines.append(LineString(ring))
    if open_lines:
        merged = linemerge(open_lines)
        polys = list(polygonize(merged))
        if not polys:
            report.skipped_unclosed += 1
        closed.extend(polys)
    return closed


def _footprint(raw: _RawBuilding, frame: LocalFrame, report: LoadReport) -> Polygon | MultiPolygon | None:
    def local(ring: list[tuple[float, float]]) -> np.ndarray:
        if not ring:
            return np.zeros((0, 2))
        arr = np.asarray(ring, dtype=float)
        x, y = frame.to_local(arr[:, 1], arr[:, 0])
        return np.column_stack([x, y])

    outer_rings = [local(r) for r in raw.outers]
    inner_rings = [local(r) for r in raw.inners]
    if raw.from_relation:
        outers = _relation_rings(outer_rings, report)
        inners = _relation_rings(inner_rings, report)
    else:
        outers = [p for p in (_ring_polygon(r, report) for r in outer_rings) if p is not None]
        inners = [p for p in (_ring_polygon(r, report) for r in inner_rings) if p is not None]
    if not outers:
        if not raw.from_relation and not any(len(r) for r in outer_rings):
            report.skipped_degenerate += 1
        return None
    repaired = False
    fixed_outers = []
    for poly in outers:
        if not poly.is_valid:
            poly, repaired = shapely.make_valid(poly), True
        fixed_outers.append(poly)
    shape = unary_union(fixed_outers)
    if inners:
        holes = unary_union([p if p.is_valid else shapely.make_valid(p) for p in inners])
        shape = shape.difference(holes)
    polys = [g for g in getattr(shape, "geoms", [shape]) if isinstance(g, Polygon) and g.area >= MIN_AREA_M2]
    if not polys:
        report.skipped_degenerate += 1
        return None
    if repaired:
        report.repaired_invalid += 1
    return polys[0] if len(polys) == 1 else MultiPolygon(polys)


def _polygon_facades(geom: Polygon | MultiPolygon) -> tuple[np.ndarray, np.ndarray]:
    """Edges (start, end) of all rings, exterior counter-clockwise and holes clockwise."""
    starts, ends = [], []
    for poly in getattr(geom, "geoms", [geom]):
        poly = orient(poly, sign=1.0)
        for ring in [poly.exterior, *poly.interiors]:
            coords = np.asarray(ring.coords)
            starts.append(coords[:-1])
            ends.append(coords[1:])
    return np.concatenate(starts), np.concatenate(ends)


def _build_city_map(raw: _RawMap, source: str, frame: LocalFrame | None = None) -> CityMap:
    report = raw.report
    all_lonlat = [p for b in raw.buildings for ring in b.outers for p in ring]
    if not all_lonlat:
        raise MapLoadError(f"{source}: no buildings found in the map data")
    arr = np.asarray(all_lonlat)
    if frame is None:
        frame = frame_for_bbox(arr[:, 1].min(), arr[:, 0].min(), arr[:, 1].max(), arr[:, 0].max())

    raw_buildings = (
        sorted(raw.buildings, key=lambda b: _osm_sort_key(b.osm_id))
        if raw.format == "pbf" or raw.format.startswith("osm")
        else raw.buildings
    )
    buildings: list[Building] = []
    starts, ends, owners = [], [], []
    for raw_building in raw_buildings:
        footprint = _footprint(raw_building, frame, report)
        if footprint is None:
            continue
        height_m, height_source = _parse_height(raw_building.tags)
        building_id = len(buildings)
        kept_tags = {k: v for k, v in raw_building.tags.items() if k in _KEPT_TAGS}
        buildings.append(
            Building(
                building_id,
                raw_building.osm_id,
                raw_building.tags.get("name"),
                height_m,
                height_source,
                footprint,
                kept_tags,
            )
        )
        s, e = _polygon_facades(footprint)
        starts.append(s)
        ends.append(e)
        owners.append(np.full(len(s), building_id, dtype=np.int32))
    if not buildings:
        raise MapLoadError(f"{source}: the map data has buildings but none with usable geometry")

    start, end, owner = np.concatenate(starts), np.concatenate(ends), np.concatenate(owners)
    direction = end - start
    length = np.hypot(direction[:, 0], direction[:, 1])
    keep = length >= MIN_FACADE_LENGTH_M
    report.short_facades_dropped += int((~keep).sum())
    start, end, direction, length, owner = start[keep], end[keep], direction[keep], length[keep], owner[keep]
    # Exterior rings run counter-clockwise, so the building is on the left: outward = right-hand normal.
    normal = np.column_stack([direction[:, 1], -direction[:, 0]]) / length[:, None]
    facades = Facades(start, end, normal, bearing_deg(normal[:, 0], normal[:, 1]), length, owner)

    trees = _to_local(frame, raw.trees)
    streets = [_to_local(frame, s) for s in raw.streets]
    extent = [arr]
    if raw.trees:
        extent.append(np.asarray(raw.trees))
    ext = np.concatenate(extent)
    bbox = (float(ext[:, 1].min()), float(ext[:, 0].min()), float(ext[:, 1].max()), float(ext[:, 0].max()))
    heights = np.array([b.height_m for b in buildings])
    return CityMap(frame, buildings, facades, heights, trees, streets, bbox, report, source)


_KEPT_TAGS = {"building", "name", "height", "building:levels", "addr:street", "addr:housenumber", "amenity"}


def _osm_sort_key(osm_id: str) -> tuple[str, int]:
    kind, _, number = osm_id.partition("/")
    return kind, int(number) if number.isdigit() else math.inf


def _to_local(frame: LocalFrame, lonlat: list[tuple[float, float]]) -> np.ndarray:
    if not lonlat:
        return np.zeros((0, 2))
    arr = np.asarray(lonlat, dtype=float)
    x, y = frame.to_local(arr[:, 1], arr[:, 0])
    return np.column_stack([x, y])
