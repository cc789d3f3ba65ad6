"""From what a reader found (:class:`RawMap`: rings and polygons in lon/lat) to a :class:`CityMap`.

Geometry problems are repaired or skipped and counted in the :class:`LoadReport`, never raised:
unclosed ways are closed when the gap is under ``MAX_CLOSING_GAP_M`` (else skipped), rings with
fewer than 3 distinct points or polygons under ``MIN_AREA_M2`` are skipped, invalid polygons
(self-intersections, overlapping parts) are repaired with shapely's ``make_valid``. Relations
contribute their outer rings (joined when split over several ways) minus their inner rings.

Building ids follow the order of the :class:`RawMap`: relations, then ways, then GIS features (the
OSM reader sorts relations and ways by id, so ids are stable for a file). Heights: the height
attribute (metres, units stripped), else the levels attribute x 3 m, else ``DEFAULT_HEIGHT_M``.

The work is vectorised over all buildings (one coordinate transform, array-wide validity,
orientation and edge extraction), so a 100,000-building map builds in seconds; only relations and
multi-part footprints are handled one by one.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import linemerge, polygonize, unary_union

from geoloc.core.geo import LocalFrame, bearing_deg, frame_for_bbox
from geoloc.maps.model import (
    Building,
    CityMap,
    Facades,
    LoadReport,
    MapLoadError,
    MapReadOptions,
)

DEFAULT_HEIGHT_M = 12.0
"""Height of a building with neither a height nor a levels attribute (about four storeys)."""
LEVEL_HEIGHT_M = 3.0
MAX_CLOSING_GAP_M = 5.0
MIN_AREA_M2 = 1.0
MIN_FACADE_LENGTH_M = 0.1
_CLOSED_TOLERANCE_M = 1e-3
_KEPT_TAGS = {"building", "name", "height", "building:levels", "addr:street", "addr:housenumber", "amenity"}
_KEPT_PREFIXES = ("addr:", "name:", "alt_name", "official_name", "short_name", "old_name")
"""Also kept: every address tag and the building's other names (the place search reads them)."""
_NUMBER = re.compile(r"^\s*([0-9]+(?:[.,][0-9]+)?)\s*(m|meters|metres)?\s*$")
_POLYGON = shapely.GeometryType.POLYGON


@dataclass
class RawRelation:
    """A multipolygon building: its member ways' coordinates as (N, 2) lon/lat arrays."""

    osm_id: str
    tags: dict[str, str]
    outers: list[np.ndarray]
    inners: list[np.ndarray]


@dataclass
class RawMap:
    """What a reader found, in lon/lat degrees (WGS84), before any geometry checks.

    Buildings come in three kinds, numbered in this order: ``relations``; ways (one ring each:
    ``way_coords`` (N, 2) split by ``way_offsets`` (W + 1,)); GIS ``features`` (shapely polygons).
    trees: (T, 2); streets: ``street_lonlat`` split by ``street_offsets``, their ``street_names`` ("" when
    unnamed); landmarks: named points (``landmark_lonlat`` (L, 2), ``landmark_names``).
    """

    format: str
    report: LoadReport
    relations: list[RawRelation] = field(default_factory=list)
    way_ids: list[str] = field(default_factory=list)
    way_tags: list[dict[str, str]] = field(default_factory=list)
    way_coords: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    way_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, dtype=np.int64))
    feature_ids: list[str] = field(default_factory=list)
    feature_tags: list[dict[str, str]] = field(default_factory=list)
    feature_geoms: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=object))
    trees: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    street_lonlat: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    street_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, dtype=np.int64))
    street_names: list[str] = field(default_factory=list)
    landmark_lonlat: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    landmark_names: list[str] = field(default_factory=list)


def build_city_map(
    raw: RawMap, source: str, options: MapReadOptions | None = None, frame: LocalFrame | None = None
) -> CityMap:
    """The :class:`CityMap` of a :class:`RawMap`; ``frame`` defaults to the one centred on its buildings."""
    options = options or MapReadOptions()
    report = raw.report
    building_lonlat = _building_lonlat(raw)
    if not len(building_lonlat):
        raise MapLoadError(f"{source}: no buildings found in the map data")
    if frame is None:
        lo, hi = building_lonlat.min(axis=0), building_lonlat.max(axis=0)
        frame = frame_for_bbox(lo[1], lo[0], hi[1], hi[0])

    candidates = np.empty(len(raw.relations) + len(raw.way_ids) + len(raw.feature_ids), dtype=object)
    candidates[: len(raw.relations)] = _relation_footprints(raw.relations, frame, report)
    n_rel, n_way = len(raw.relations), len(raw.way_ids)
    candidates[n_rel : n_rel + n_way] = _way_polygons(raw.way_coords, raw.way_offsets, frame, report)
    if len(raw.feature_geoms):
        candidates[n_rel + n_way :] = shapely.transform(raw.feature_geoms, lambda lonlat: _local(frame, lonlat))
    ids = [r.osm_id for r in raw.relations] + list(raw.way_ids) + list(raw.feature_ids)
    tags = [r.tags for r in raw.relations] + list(raw.way_tags) + list(raw.feature_tags)

    parts, owner = _clean_parts(candidates, report)
    if not len(parts):
        raise MapLoadError(f"{source}: the map data has buildings but none with usable geometry")
    kept, first = np.unique(owner, return_index=True)
    count = np.diff(np.r_[first, len(owner)])
    part_building = np.repeat(np.arange(len(kept)), count).astype(np.int32)
    buildings = _buildings(kept, first, count, parts, ids, tags, options)
    facades = _facades(parts, part_building, report)

    trees = _local(frame, raw.trees)
    extent = np.concatenate([building_lonlat, raw.trees]) if len(raw.trees) else building_lonlat
    bbox = (float(extent[:, 1].min()), float(extent[:, 0].min()), float(extent[:, 1].max()), float(extent[:, 0].max()))
    heights = np.array([b.height_m for b in buildings])
    street_names = raw.street_names or [""] * (len(raw.street_offsets) - 1)
    return CityMap(
        frame,
        buildings,
        facades,
        heights,
        trees,
        raw.street_lonlat,
        raw.street_offsets,
        bbox,
        report,
        source,
        street_names=list(street_names),
        landmark_lonlat=np.asarray(raw.landmark_lonlat, dtype=float).reshape(-1, 2),
        landmark_names=list(raw.landmark_names),
    )


def parse_height(tags: dict[str, str], options: MapReadOptions | None = None) -> tuple[float, str]:
    """(height in metres, source) from a building's attributes: ``height``, ``levels`` or ``default``."""
    options = options or MapReadOptions()
    height = _NUMBER.match(tags.get(options.height_attribute, ""))
    if height:
        value = float(height.group(1).replace(",", "."))
        if 1.0 <= value <= 500.0:
            return value, "height"
    levels = _NUMBER.match(tags.get(options.levels_attribute, ""))
    if levels:
        value = float(levels.group(1).replace(",", "."))
        if 0.5 <= value <= 150.0:
            return value * LEVEL_HEIGHT_M, "levels"
    return DEFAULT_HEIGHT_M, "default"


# ----------------------------------------------------------------------------------------------


def _building_lonlat(raw: RawMap) -> np.ndarray:
    rings = [ring for r in raw.relations for ring in r.outers if len(ring)]
    chunks = [np.asarray(r, dtype=float).reshape(-1, 2) for r in rings] + [raw.way_coords]
    if len(raw.feature_geoms):
        chunks.append(shapely.get_coordinates(raw.feature_geoms))
    return np.concatenate(chunks) if chunks else np.zeros((0, 2))


def _local(frame: LocalFrame, lonlat: np.ndarray) -> np.ndarray:
    """(N, 2) lon/lat -> (N, 2) local metres, in one transform."""
    lonlat = np.asarray(lonlat, dtype=float).reshape(-1, 2)
    if not len(lonlat):
        return np.zeros((0, 2))
    x, y = frame.to_local(lonlat[:, 1], lonlat[:, 0])
    return np.column_stack([x, y])


def _way_polygons(coords: np.ndarray, offsets: np.ndarray, frame: LocalFrame, report: LoadReport) -> np.ndarray:
    """One polygon (or None, counted) per way ring, vectorised over all ways."""
    n_ways = len(offsets) - 1
    out = np.empty(n_ways, dtype=object)
    if n_ways == 0:
        return out
    xy = _local(frame, coords)
    n = np.diff(offsets)
    first, last = offsets[:-1], np.maximum(offsets[1:] - 1, offsets[:-1])
    gap = np.zeros(n_ways)
    two = n >= 2
    gap[two] = np.hypot(*(xy[last[two]] - xy[first[two]]).T)
    open_ring = two & (gap > _CLOSED_TOLERANCE_M)
    too_open = open_ring & (gap > MAX_CLOSING_GAP_M)
    report.skipped_unclosed += int(too_open.sum())
    report.closed_unclosed_ways += int((open_ring & ~too_open).sum())
    degenerate = ~too_open & (_distinct_points(xy, n) < 3)
    report.skipped_degenerate += int(degenerate.sum())
    ok = ~too_open & ~degenerate
    ring_of_point = np.repeat(np.arange(n_ways), n)
    take = ok[ring_of_point]
    compact = np.cumsum(ok) - 1  # ring index among the usable ones
    # shapely closes rings whose last point differs from the first (the gap was checked above).
    rings = shapely.linearrings(xy[take], indices=compact[ring_of_point[take]])
    out[ok] = shapely.polygons(rings)
    return out


def _distinct_points(xy: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Distinct points (to the millimetre) per ring of ``xy`` split by counts ``n``."""
    ring = np.repeat(np.arange(len(n)), n)
    if not len(ring):
        return np.zeros(len(n), dtype=np.int64)
    mm = np.round(xy * 1000.0).astype(np.int64)
    order = np.lexsort((mm[:, 1], mm[:, 0], ring))
    r, p = ring[order], mm[order]
    new = np.r_[True, (r[1:] != r[:-1]) | np.any(p[1:] != p[:-1], axis=1)]
    return np.bincount(r[new], minlength=len(n))


def _relation_footprints(
    relations: list[RawRelation], frame: LocalFrame, report: LoadReport
) -> list[Polygon | MultiPolygon | None]:
    """Footprints of all relations (their rings transformed to the local frame in one go).

    Relations whose member ways are each a closed ring (most of them) are built together by
    :func:`_closed_ring_footprints`; the others, whose rings must first be joined, one by one.
    """
    rings = [ring for r in relations for ring in (*r.outers, *r.inners)]
    if not rings:
        return [None] * len(relations)
    bounds = np.r_[0, np.cumsum([len(ring) for ring in rings])].tolist()
    xy = _local(frame, np.concatenate(rings))
    local = iter([xy[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)])
    out: list[Polygon | MultiPolygon | None] = [None] * len(relations)
    closed_index: list[int] = []
    closed: list[tuple[list[np.ndarray], list[np.ndarray]]] = []
    for index, relation in enumerate(relations):
        outers = [ring for _ in relation.outers if len(ring := next(local))]
        inners = [ring for _ in relation.inners if len(ring := next(local))]
        if outers and all(_is_closed(ring) for ring in (*outers, *inners)):
            closed_index.append(index)
            closed.append((outers, inners))
        else:
            out[index] = _relation_footprint(outers, inners, report)
    for index, footprint in zip(closed_index, _closed_ring_footprints(closed, report), strict=True):
        out[index] = footprint
    return out


def _is_closed(ring: np.ndarray) -> bool:
    """A ring of at least 4 points whose last point is its first (to :data:`_CLOSED_TOLERANCE_M`)."""
    return len(ring) >= 4 and float(np.abs(ring[0] - ring[-1]).max()) <= _CLOSED_TOLERANCE_M


def _closed_ring_footprints(
    relations: list[tuple[list[np.ndarray], list[np.ndarray]]], report: LoadReport
) -> list[Polygon | MultiPolygon | None]:
    """:func:`_relation_footprint` of relations (outer rings, inner rings) whose rings are all closed, vectorised.

    The same GEOS operations in the same order (each ring a polygon, invalid ones made valid; per relation the
    union of its outers minus the union of its inners), so the footprints are those of the one-by-one path.
    """
    if not relations:
        return []
    counts = np.array([(len(outers), len(inners)) for outers, inners in relations])
    all_rings = [ring for outers, inners in relations for ring in (*outers, *inners)]
    sizes = np.array([len(ring) for ring in all_rings])
    polygons: np.ndarray = np.asarray(
        shapely.polygons(
            shapely.linearrings(np.concatenate(all_rings), indices=np.repeat(np.arange(len(all_rings)), sizes))
        )
    )
    invalid = ~shapely.is_valid(polygons)
    polygons[invalid] = shapely.make_valid(polygons[invalid])
    rings_per_relation = counts.sum(axis=1)
    ring_relation = np.repeat(np.arange(len(relations)), rings_per_relation)
    first_ring = np.cumsum(rings_per_relation) - rings_per_relation
    ring_rank = np.arange(len(all_rings)) - first_ring[ring_relation]  # its place among its relation's rings
    is_outer = ring_rank < counts[ring_relation, 0]  # outers first, as listed

    def union_per_relation(select: np.ndarray, rank: np.ndarray) -> np.ndarray:
        # One row per relation, padded with None (which union_all ignores): each row's union in one call.
        table = np.full((len(relations), int(rank[select].max()) + 1), None, dtype=object)
        table[ring_relation[select], rank[select]] = polygons[select]
        return np.asarray(shapely.union_all(table, axis=1))

    shapes = union_per_relation(is_outer, ring_rank)
    holed = counts[:, 1] > 0
    if holed.any():
        holes = union_per_relation(~is_outer, ring_rank - counts[ring_relation, 0])
        shapes[holed] = shapely.difference(shapes[holed], holes[holed])
    parts, part_relation = shapely.get_parts(shapes, return_index=True)
    keep = (shapely.get_type_id(parts) == _POLYGON) & (shapely.area(parts) >= MIN_AREA_M2)
    parts, part_relation = parts[keep], part_relation[keep]
    per_relation = np.bincount(part_relation, minlength=len(relations))
    repaired = np.bincount(ring_relation[invalid & is_outer], minlength=len(relations)) > 0
    report.skipped_degenerate += int((per_relation == 0).sum())
    report.repaired_invalid += int((repaired & (per_relation > 0)).sum())
    starts = np.r_[0, np.cumsum(per_relation)[:-1]]
    return [
        None if n == 0 else parts[start] if n == 1 else MultiPolygon(list(parts[start : start + n]))
        for start, n in zip(starts.tolist(), per_relation.tolist(), strict=True)
    ]


def _relation_footprint(
    outer_rings: list[np.ndarray], inner_rings: list[np.ndarray], report: LoadReport
) -> Polygon | MultiPolygon | None:
    """A relation's outer rings (joined) minus its inner rings (local metres); None (counted) if unusable."""
    outers = _relation_rings(outer_rings, report)
    inners = _relation_rings(inner_rings, report)
    if not outers:
        return None
    repaired = False
    fixed: list[BaseGeometry] = []
    for poly in outers:
        if poly.is_valid:
            fixed.append(poly)
        else:
            fixed.append(shapely.make_valid(poly))
            repaired = True
    shape = unary_union(fixed)
    if inners:
        shape = shape.difference(unary_union([p if p.is_valid else shapely.make_valid(p) for p in inners]))
    polys = [g for g in getattr(shape, "geoms", [shape]) if isinstance(g, Polygon) and g.area >= MIN_AREA_M2]
    if not polys:
        report.skipped_degenerate += 1
        return None
    if repaired:
        report.repaired_invalid += 1
    return polys[0] if len(polys) == 1 else MultiPolygon(polys)


def _relation_rings(rings: list[np.ndarray], report: LoadReport) -> list[Polygon]:
    """Join a relation's member ways into closed rings (they may be split across several ways)."""
    closed, open_lines = [], []
    for ring in rings:
        if _is_closed(ring):
            closed.append(Polygon(ring))
        elif len(ring) >= 2:
            open_lines.append(LineString(ring))
    if open_lines:
        polys = list(polygonize(linemerge(open_lines)))
        if not polys:
            report.skipped_unclosed += 1
        closed.extend(polys)
    return closed


def _clean_parts(candidates: np.ndarray, report: LoadReport) -> tuple[np.ndarray, np.ndarray]:
    """Valid polygon parts of at least ``MIN_AREA_M2``, exterior counter-clockwise, and their candidate index.

    Invalid candidates are repaired with ``make_valid`` (counted when something usable remains);
    candidates with nothing usable are counted as degenerate (None ones were counted by their reader).
    """
    present = ~shapely.is_missing(candidates)
    invalid = present & ~shapely.is_valid(candidates)
    fixed = candidates.copy()
    if invalid.any():
        # The union after make_valid merges overlapping pieces (and fixes the rings' start vertices).
        fixed[invalid] = [unary_union([g]) for g in shapely.make_valid(candidates[invalid])]
    parts, owner = shapely.get_parts(fixed, return_index=True)
    while len(parts) and np.any(nested := shapely.get_num_geometries(parts) > 1):
        # make_valid may return collections holding multipolygons: flatten until single parts remain.
        sub, sub_owner = shapely.get_parts(parts[nested], return_index=True)
        parts = np.concatenate([parts[~nested], sub])
        owner = np.concatenate([owner[~nested], owner[nested][sub_owner]])
    keep = (shapely.get_type_id(parts) == _POLYGON) & (shapely.area(parts) >= MIN_AREA_M2)
    parts, owner = parts[keep], owner[keep]
    order = np.argsort(owner, kind="stable")
    parts, owner = parts[order], owner[order]
    usable = np.zeros(len(candidates), dtype=bool)
    usable[owner] = True
    report.skipped_degenerate += int((present & ~usable).sum())
    report.repaired_invalid += int((invalid & usable).sum())
    return shapely.orient_polygons(parts, exterior_cw=False), owner


def _buildings(
    kept: np.ndarray,
    first: np.ndarray,
    count: np.ndarray,
    parts: np.ndarray,
    ids: list[str],
    tags: list[dict[str, str]],
    options: MapReadOptions,
) -> list[Building]:
    kept_tags = _KEPT_TAGS | {options.name_attribute, options.height_attribute, options.levels_attribute}
    buildings = []
    rows = zip(kept.tolist(), first.tolist(), count.tolist(), strict=True)
    for building_id, (candidate, start, n) in enumerate(rows):
        attributes = tags[candidate]
        height_m, height_source = parse_height(attributes, options)
        polygon = parts[start] if n == 1 else MultiPolygon(list(parts[start : start + n]))
        buildings.append(
            Building(
                building_id,
                ids[candidate],
                attributes.get(options.name_attribute) or None,
                height_m,
                height_source,
                polygon,
                {k: v for k, v in attributes.items() if k in kept_tags or k.startswith(_KEPT_PREFIXES)},
            )
        )
    return buildings


def _facades(parts: np.ndarray, part_building: np.ndarray, report: LoadReport) -> Facades:
    """Edges of every ring of the oriented parts (the building on the left), with outward normals."""
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    coords, point_ring = shapely.get_coordinates(rings, return_index=True)
    edge = np.flatnonzero(point_ring[1:] == point_ring[:-1])
    start, end = coords[edge], coords[edge + 1]
    owner = part_building[ring_part[point_ring[edge]]]
    direction = end - start
    length = np.hypot(direction[:, 0], direction[:, 1])
    keep = length >= MIN_FACADE_LENGTH_M
    report.short_facades_dropped += int((~keep).sum())
    start, end, direction, length, owner = start[keep], end[keep], direction[keep], length[keep], owner[keep]
    # The building is on the left of each edge, so the outward normal is the right-hand one.
    normal = np.column_stack([direction[:, 1], -direction[:, 0]]) / length[:, None]
    return Facades(start, end, normal, bearing_deg(normal[:, 0], normal[:, 1]), length, owner.astype(np.int32))
