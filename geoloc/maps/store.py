"""A loaded :class:`CityMap` as one binary file, so a process that needs a map does not parse its source again.

The file is an uncompressed ``.npz`` (no pickle, :mod:`geoloc.core.array_file`): the facade, tree, street and
landmark arrays as they are, the facades' cell index (:class:`geoloc.maps.spatial.FacadeIndex`, built once when
the file is written), the footprints as concatenated WKB, and the rest (frame origin, bounds, names, street and
landmark names, ids, tags, heights, report) as JSON. :func:`read_city_map` memory-maps it: the arrays are
read-only views of the file's pages, shared by every worker process of the machine through the page cache, and
only the buildings (footprints, names, tags) are decoded: under a second for a 100,000-building map, where
parsing the OSM extract takes a minute. The map job writes the file when it stores the map
(:mod:`workers.map_handlers`); :func:`load_map_cached` keeps such a file per (source checksum, read options,
:data:`CACHE_VERSION`) in a cache folder; the name changes whenever the loader's output could, so a stale file
is never read (an older version's file is left alone and the map parsed again).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from dataclasses import fields
from pathlib import Path

import numpy as np
import shapely

from geoloc.core.array_file import map_arrays, write_arrays
from geoloc.core.geo import LocalFrame
from geoloc.maps.model import Building, CityMap, Facades, LoadReport, MapReadOptions
from geoloc.maps.spatial import FacadeIndex

CACHE_VERSION = 4
"""Bumped whenever loading could give a different map for the same file and options, or the file's layout
changes (2, 3: street names, landmarks, all address tags; 3 because two unreleased branches each wrote a
different version 2; 4: memory-mapped, with the facade index and the bounds)."""


def map_cache_dir(data_dir: Path) -> Path:
    """The folder of cached maps under a data folder (``GEOLOC_DATA_DIR``): ``DATA_DIR/cache/maps``."""
    return Path(data_dir) / "cache" / "maps"


def map_cache_path(cache_dir: Path, sha256: str, options: MapReadOptions | None = None) -> Path:
    """Where :func:`load_map_cached` keeps the map of a source file (by its sha256) read with ``options``."""
    key = json.dumps((options or MapReadOptions()).as_dict(), sort_keys=True)
    suffix = hashlib.sha256(key.encode()).hexdigest()[:12]
    return Path(cache_dir) / f"{sha256}-{suffix}-v{CACHE_VERSION}.citymap.npz"


def save_city_map(city_map: CityMap, path: Path) -> None:
    """Write ``city_map`` to ``path`` (atomically: a reader sees the old file, none, or the whole new one)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buildings = city_map.buildings
    wkb = shapely.to_wkb(city_map.footprints)
    offsets = np.r_[0, np.cumsum([len(b) for b in wkb])].astype(np.int64)
    meta = {
        "version": CACHE_VERSION,
        "bounds_m": list(city_map.bounds_m),
        "origin": [city_map.frame.origin_lat, city_map.frame.origin_lon],
        "bbox_wgs84": list(city_map.bbox_wgs84),
        "report": city_map.report.as_dict(),
        "source": city_map.source,
        "osm_ids": [b.osm_id for b in buildings],
        "names": [b.name for b in buildings],
        "height_sources": [b.height_source for b in buildings],
        "tags": [b.tags for b in buildings],
        "street_names": city_map.street_names,
        "landmark_names": city_map.landmark_names,
    }
    arrays = {
        "meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
        "footprints_wkb": np.frombuffer(b"".join(wkb), dtype=np.uint8),
        "footprints_offsets": offsets,
        "heights_m": np.asarray(city_map.building_height_m, dtype=float),
        "trees": city_map.trees,
        "street_lonlat": city_map.street_lonlat,
        "street_offsets": city_map.street_offsets,
        "landmark_lonlat": np.asarray(city_map.landmark_lonlat, dtype=float).reshape(-1, 2),
        **{f"facades_{f.name}": getattr(city_map.facades, f.name) for f in fields(Facades)},
        **{f"facade_index_{name}": a for name, a in city_map.facade_index.arrays().items()},
    }
    write_arrays(path, arrays)


def read_city_map(path: Path) -> CityMap:
    """The map written by :func:`save_city_map`, its arrays memory-mapped read-only (module docstring).

    ``ValueError`` if the file is not one (or another version).
    """
    arrays = map_arrays(Path(path))
    if "meta" not in arrays:
        raise ValueError(f"{Path(path).name}: not a stored map")
    meta = json.loads(arrays["meta"].tobytes())
    if meta.get("version") != CACHE_VERSION:
        raise ValueError(f"{path}: stored map version {meta.get('version')}, expected {CACHE_VERSION}")
    blob, offsets = arrays["footprints_wkb"].tobytes(), arrays["footprints_offsets"]
    polygons = shapely.from_wkb([blob[a:b] for a, b in zip(offsets[:-1].tolist(), offsets[1:].tolist(), strict=True)])
    heights = arrays["heights_m"]
    buildings = [
        Building(i, osm_id, name, float(height), source, polygon, tags)
        for i, (osm_id, name, height, source, polygon, tags) in enumerate(
            zip(
                meta["osm_ids"],
                meta["names"],
                heights.tolist(),
                meta["height_sources"],
                polygons,
                meta["tags"],
                strict=True,
            )
        )
    ]
    facades = Facades(**{f.name: arrays[f"facades_{f.name}"] for f in fields(Facades)})
    city_map = CityMap(
        LocalFrame(*meta["origin"]),
        buildings,
        facades,
        heights,
        arrays["trees"],
        arrays["street_lonlat"],
        arrays["street_offsets"],
        tuple(meta["bbox_wgs84"]),
        LoadReport(**meta["report"]),
        meta["source"],
        street_names=meta["street_names"],
        landmark_lonlat=arrays["landmark_lonlat"],
        landmark_names=meta["landmark_names"],
    )
    # The indexes computed when the file was written, where the cached properties look first (instance dict).
    index = {name.removeprefix("facade_index_"): a for name, a in arrays.items() if name.startswith("facade_index_")}
    vars(city_map)["facade_index"] = FacadeIndex.from_arrays(facades, index)
    vars(city_map)["bounds_m"] = tuple(float(v) for v in meta["bounds_m"])
    return city_map


def remove_cached_map(cache_dir: Path, sha256: str, options: MapReadOptions | None = None) -> None:
    """Delete the cached map of a source file and options, if any."""
    with contextlib.suppress(OSError):
        map_cache_path(cache_dir, sha256, options).unlink(missing_ok=True)
