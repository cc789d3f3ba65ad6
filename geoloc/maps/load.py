"""Entry points of map loading.

:func:`load_map` (any accepted file -> :class:`CityMap`), :func:`load_map_cached`,
:func:`city_map_from_footprints` (hand-made scenes) and :func:`map_summary` (``geoloc map info``).
"""

from __future__ import annotations

import hashlib
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.core.geo import LocalFrame
from geoloc.maps.build import RawMap, build_city_map
from geoloc.maps.gis_reader import read_gis
from geoloc.maps.model import CityMap, LoadReport, MapLoadError, MapProgress, MapReadOptions
from geoloc.maps.osm_reader import read_osm
from geoloc.maps.sniff import OSM_FORMATS, sniff_format
from geoloc.maps.store import map_cache_path, read_city_map, save_city_map


def load_map(path: str | Path, options: MapReadOptions | None = None, progress: MapProgress | None = None) -> CityMap:
    """Load the buildings (with facades), trees and streets of a map file.

    Accepted, told from the content: OSM XML (plain, .bz2, .gz), .osm.pbf, GeoJSON (plain, .gz),
    GeoPackage, FlatGeobuf and zipped Shapefiles (see :mod:`geoloc.maps`). ``options`` choose the GIS
    layer, the attributes holding names and heights, and the CRS. Raises :class:`MapLoadError` with a
    reason when the file is not map data, holds no usable buildings or cannot be placed on the globe.
    progress: told (elements read, buildings so far) while the file is read (:data:`MapProgress`).
    """
    path = Path(path)
    options = options or MapReadOptions()
    if not path.is_file():
        raise MapLoadError(f"{path} is not a file")
    kind = sniff_format(path)
    if kind in OSM_FORMATS:
        if options.layer is not None:
            raise MapLoadError(f"{path.name}: OSM data has no layers (the layer option is for GIS files)")
        if options.crs is not None:
            raise MapLoadError(f"{path.name}: OSM data is always WGS84 (the crs option is for GIS files)")
        raw = read_osm(path, kind, progress)
    else:
        raw = read_gis(path, kind, options)
    if progress is not None:  # read: the building candidates (ways, relations, features) are known
        candidates = len(raw.relations) + len(raw.way_ids) + len(raw.feature_ids)
        progress(candidates, candidates)
    return build_city_map(raw, path.name, options)


def load_map_cached(
    path: str | Path, cache_dir: Path, options: MapReadOptions | None = None, sha256: str | None = None
) -> CityMap:
    """:func:`load_map`, through a stored copy in ``cache_dir`` (:mod:`geoloc.maps.store`) made on first use.

    sha256: the file's checksum if known (else computed). An unreadable stored copy is replaced.
    """
    path = Path(path)
    cached = map_cache_path(cache_dir, sha256 or file_sha256(path), options)
    if cached.is_file():
        try:
            return read_city_map(cached)
        except (ValueError, KeyError, TypeError):
            pass  # damaged or foreign: load the source again and replace it
    city_map = load_map(path, options)
    save_city_map(city_map, cached)
    return city_map


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's content."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


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
    rings = [np.asarray(ring, dtype=float).reshape(-1, 2) for ring in footprints_m]
    rings = [ring if np.allclose(ring[0], ring[-1]) else np.vstack([ring, ring[:1]]) for ring in rings]
    xy = np.concatenate(rings) if rings else np.zeros((0, 2))
    lat, lon = frame.to_wgs84(xy[:, 0], xy[:, 1])
    raw = RawMap("footprints", LoadReport("footprints"))
    raw.way_coords = np.column_stack([lon, lat])
    raw.way_offsets = np.r_[0, np.cumsum([len(r) for r in rings])].astype(np.int64)
    raw.way_ids = [f"way/{i + 1}" for i in range(len(rings))]
    raw.way_tags = []
    for i in range(len(rings)):
        tags = {"building": "yes"}
        if heights_m is not None:
            tags["height"] = str(heights_m[i])
        if names is not None and names[i]:
            tags["name"] = str(names[i])
        raw.way_tags.append(tags)
    return build_city_map(raw, "footprints", frame=frame)


def map_summary(city_map: CityMap) -> dict[str, Any]:
    """A JSON-ready summary: counts, bounding box, named buildings, repair report."""
    named = [b for b in city_map.buildings if b.name]
    return {
        "source": city_map.source,
        "buildings": len(city_map.buildings),
        "facades": len(city_map.facades),
        "named_buildings": len(named),
        "named_examples": sorted({b.name for b in named if b.name})[:10],
        "trees": len(city_map.trees),
        "streets": len(city_map.street_offsets) - 1,
        "bbox_wgs84": dict(zip(("min_lat", "min_lon", "max_lat", "max_lon"), city_map.bbox_wgs84, strict=True)),
        "origin_wgs84": {"lat": city_map.frame.origin_lat, "lon": city_map.frame.origin_lon},
        "extent_m": [round(v, 1) for v in city_map.bounds_m],
        "height_sources": dict(Counter(b.height_source for b in city_map.buildings)),
        "report": city_map.report.as_dict(),
    }
