"""OpenStreetMap data (XML plain/.bz2/.gz, PBF) -> :class:`RawMap`, with pyosmium.

What counts as a building: ways and ``type=multipolygon`` relations tagged ``building=*`` (not
``building=no``); ``building:part`` ways are counted but not used (parts overlap their building).
Also read: ``natural=tree`` nodes, ``highway=*`` ways with their names (street furniture of the simulator,
streets of the place search) and landmarks: named nodes tagged as one of :data:`LANDMARK_KEYS`.

Two passes keep a city extract cheap: the first reads only relations (to learn which ways are
members of building relations); the second reads nodes and ways with node locations cached in
C++, where a filter hands only ``natural=*`` nodes to Python, and way geometries are built in C++
(WKB) rather than node by node. Node references missing from the extract are dropped (counted;
only for the ways used); a relation with member ways missing from the extract is skipped (counted).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import osmium
import shapely

from geoloc.maps.build import RawMap, RawRelation
from geoloc.maps.model import PROGRESS_EVERY, LoadReport, MapLoadError, MapProgress
from geoloc.maps.sniff import check_compressed_stream

_OSMIUM_FORMATS = {"osm": "osm", "osm.bz2": "osm.bz2", "osm.gz": "osm.gz", "pbf": "pbf"}
LANDMARK_KEYS = ("tourism", "historic", "amenity", "leisure", "shop", "office", "place")
"""A named node with one of these keys is a landmark (a sight, a shop, a square), or a station (railway or
public_transport ``station``); stops and platforms, named after their street, are not."""


def read_osm(path: Path, kind: str, progress: MapProgress | None = None) -> RawMap:
    """Buildings, trees and streets of an OSM file of format ``kind`` (``osm``, ``osm.bz2``, ``osm.gz``, ``pbf``).

    progress: called with (objects read, building ways so far) every :data:`PROGRESS_EVERY` objects.
    """
    try:
        return _read(path, kind, progress)
    except (RuntimeError, ValueError, OSError) as exc:  # osmium's parse and decompression errors
        check_compressed_stream(path, kind)
        raise MapLoadError(f"{path.name}: cannot read OSM data: {exc}") from exc


def _is_building(tags: Any) -> bool:
    value = tags.get("building")
    return value is not None and value != "no"


def _is_landmark(tags: Any) -> bool:
    """A station, or tagged with one of :data:`LANDMARK_KEYS` (asked of named nodes only: most nodes have no name)."""
    station = "station" in (tags.get("railway"), tags.get("public_transport"))
    return station or any(key in tags for key in LANDMARK_KEYS)


_Relation = tuple[int, dict[str, str], list[tuple[int, str]]]
"""A building multipolygon relation: (id, tags, [(member way id, role)])."""


def _building_relations(osm_file: Any) -> list[_Relation]:
    """The building multipolygon relations of an ``osmium.io.File``, with their member ways."""
    relations: list[_Relation] = []
    relation: Any  # pyosmium's objects (typed as a union of all kinds)
    for relation in osmium.FileProcessor(osm_file, osmium.osm.RELATION):
        tags = relation.tags
        if tags.get("type") == "multipolygon" and _is_building(tags):
            members = [(m.ref, m.role) for m in relation.members if m.type == "w"]
            relations.append((relation.id, dict(tags), members))
    return relations


def _counted(objects: Iterable[Any], progress: MapProgress | None, read: int, buildings: list[Any]) -> Iterator[Any]:
    """``objects`` as they come, telling ``progress`` (objects read, ``len(buildings)``) every PROGRESS_EVERY."""
    for obj in objects:
        read += 1
        if progress is not None and read % PROGRESS_EVERY == 0:
            progress(read, len(buildings))
        yield obj


def _read(path: Path, kind: str, progress: MapProgress | None) -> RawMap:
    report = LoadReport(format=kind)
    osm_file = osmium.io.File(str(path), _OSMIUM_FORMATS[kind])

    relations = _building_relations(osm_file)
    member_ids = {ref for _, _, members in relations for ref, _ in members}

    factory = osmium.geom.WKBFactory()
    trees: list[tuple[float, float]] = []
    landmarks: list[tuple[float, float]] = []
    landmark_names: list[str] = []
    street_names: list[str] = []
    building_ways: list[tuple[int, dict[str, str]]] = []
    building_geoms: list[Any] = []
    street_geoms: list[Any] = []
    member_geoms: dict[int, Any] = {}
    # Only tagged nodes reach Python (node locations are cached in C++ for all). Ways all do: a relation's
    # member ways are often untagged, and a filter by id costs memory in the id range on large extracts.
    natural_nodes = osmium.filter.KeyFilter("natural", "name")
    natural_nodes.enable_for(osmium.osm.NODE)  # ways all pass
    processor = osmium.FileProcessor(osm_file, osmium.osm.NODE | osmium.osm.WAY).with_locations()
    obj: Any
    for obj in _counted(processor.with_filter(natural_nodes), progress, len(relations), building_ways):
        if isinstance(obj, osmium.osm.Node):
            node_tags, location = obj.tags, obj.location
            if not location.valid():
                continue
            if node_tags.get("natural") == "tree":
                trees.append((location.lon, location.lat))
            if (name := node_tags.get("name")) and _is_landmark(node_tags):
                landmarks.append((location.lon, location.lat))
                landmark_names.append(name)
            continue
        way_tags = obj.tags
        building = way_tags.get("building")
        geometry = None
        if building is not None and building != "no":
            geometry = _way_geometry(factory, obj, report)
            building_ways.append((obj.id, dict(way_tags)))
            building_geoms.append(geometry)
        elif building is None and "building:part" in way_tags:
            report.building_parts_ignored += 1
        elif "highway" in way_tags:
            geometry = _way_geometry(factory, obj, report)
            street_geoms.append(geometry)
            street_names.append(way_tags.get("name", ""))
        if obj.id in member_ids:
            member_geoms[obj.id] = geometry if geometry is not None else _way_geometry(factory, obj, report)

    raw = RawMap(kind, report)
    order = np.argsort([way_id for way_id, _ in building_ways], kind="stable").astype(np.int64)
    raw.way_coords, raw.way_offsets = _ragged([building_geoms[i] for i in order])
    raw.way_ids = [f"way/{building_ways[i][0]}" for i in order]
    raw.way_tags = [building_ways[i][1] for i in order]
    report.building_ways = len(building_ways)
    raw.relations = _raw_relations(relations, member_geoms, report)

    street_lonlat, street_offsets = _ragged(street_geoms)
    long_enough = np.flatnonzero(np.diff(street_offsets) >= 2)
    raw.street_lonlat, raw.street_offsets = _reorder(street_lonlat, street_offsets, long_enough)
    raw.street_names = [street_names[i] for i in long_enough.tolist()]
    raw.trees = np.asarray(trees, dtype=float).reshape(-1, 2)
    raw.landmark_lonlat = np.asarray(landmarks, dtype=float).reshape(-1, 2)
    raw.landmark_names = landmark_names
    return raw


def _raw_relations(
    relations: list[_Relation], member_geoms: dict[int, str | np.ndarray], report: LoadReport
) -> list[RawRelation]:
    """The relations (by id) with their member ways' lon/lat rings; incomplete ones skipped and counted."""
    out: list[RawRelation] = []
    member_list = list(member_geoms)
    member_coords, member_offsets = _ragged([member_geoms[way_id] for way_id in member_list])
    member_rings = {
        way_id: member_coords[a:b]
        for way_id, a, b in zip(member_list, member_offsets[:-1].tolist(), member_offsets[1:].tolist(), strict=True)
    }
    for rel_id, tags, members in sorted(relations, key=lambda r: r[0]):
        report.building_relations += 1
        outers = [member_rings[ref] for ref, role in members if role != "inner" and ref in member_rings]
        inners = [member_rings[ref] for ref, role in members if role == "inner" and ref in member_rings]
        if len(outers) < sum(role != "inner" for _, role in members):
            report.skipped_incomplete_relations += 1
            continue
        out.append(RawRelation(f"relation/{rel_id}", tags, outers, inners))
    return out


def _way_geometry(factory: Any, way: Any, report: LoadReport) -> str | np.ndarray:
    """The way's node locations as hex WKB (built in C++), or an array when that cannot be built.

    When some locations are missing or there are fewer than two, returns an (N, 2) lon/lat array of
    the valid ones (the missing ones counted).
    """
    try:
        return str(factory.create_linestring(way, osmium.geom.use_nodes.ALL))
    except (osmium.InvalidLocationError, RuntimeError):
        coords = []
        for node in way.nodes:
            if node.location.valid():
                coords.append((node.location.lon, node.location.lat))
            else:
                report.missing_node_refs += 1
        return np.asarray(coords, dtype=float).reshape(-1, 2)


def _ragged(items: list[str | np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates (N, 2) of hex-WKB linestrings and (n, 2) arrays, in order, and offsets (len + 1,)."""
    is_wkb = np.fromiter((isinstance(item, str) for item in items), dtype=bool, count=len(items))
    wkb_items, array_items = np.flatnonzero(is_wkb), np.flatnonzero(~is_wkb)
    counts = np.zeros(len(items), dtype=np.int64)
    wkb_coords, wkb_counts = _linestring_coords([str(items[i]) for i in wkb_items.tolist()])
    counts[wkb_items] = wkb_counts
    arrays = [np.asarray(items[i]) for i in array_items.tolist()]
    counts[array_items] = [len(a) for a in arrays]
    offsets = np.r_[0, np.cumsum(counts)].astype(np.int64)
    coords = np.zeros((int(offsets[-1]), 2))
    for chosen, values in ((wkb_items, wkb_coords), (array_items, np.concatenate(arrays) if arrays else None)):
        if values is not None and len(values):
            n = counts[chosen]
            coords[np.repeat(offsets[chosen] - (np.cumsum(n) - n), n) + np.arange(n.sum())] = values
    return coords, offsets


def _linestring_coords(hex_wkb: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates (N, 2) and point counts of little-endian 2D WKB linestrings, decoded in one go.

    As pyosmium writes them: a 9-byte header (byte order, type, count), then x, y doubles.
    """
    if not hex_wkb:
        return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
    lengths = np.fromiter((len(h) // 2 for h in hex_wkb), dtype=np.int64, count=len(hex_wkb))
    buffer = np.frombuffer(bytes.fromhex("".join(hex_wkb)), dtype=np.uint8)
    starts = np.cumsum(lengths) - lengths
    header = (starts[:, None] + np.arange(9)).ravel()
    expected = np.tile(np.array([1, 2, 0, 0, 0], dtype=np.uint8), len(starts))
    if not np.array_equal(buffer[(starts[:, None] + np.arange(5)).ravel()], expected):
        geoms = shapely.from_wkb(np.array(hex_wkb, dtype=object))  # not the layout expected: let GEOS read it
        coords, index = shapely.get_coordinates(geoms, return_index=True)
        return coords, np.bincount(index, minlength=len(hex_wkb)).astype(np.int64)
    body = np.ones(len(buffer), dtype=bool)
    body[header] = False
    return buffer[body].view("<f8").reshape(-1, 2).astype(float), (lengths - 9) // 16


def _reorder(coords: np.ndarray, offsets: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rings ``order`` (indices) of ragged ``coords``/``offsets``, as a new ragged pair."""
    counts = np.diff(offsets)[order]
    starts = offsets[:-1][order]
    index = np.repeat(starts - (np.cumsum(counts) - counts), counts) + np.arange(counts.sum())
    return coords[index], np.r_[0, np.cumsum(counts)].astype(np.int64)
