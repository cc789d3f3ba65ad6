"""The map API under its original name: ``from geoloc.osm import load_map, CityMap, ...`` keeps working.

The code lives in :mod:`geoloc.maps` (formats, readers, building, storage); this module only re-exports it.
"""

from geoloc.maps import (
    DEFAULT_HEIGHT_M,
    LEVEL_HEIGHT_M,
    MAX_CLOSING_GAP_M,
    MIN_AREA_M2,
    Building,
    CityMap,
    Facades,
    LoadReport,
    MapLoadError,
    MapReadOptions,
    city_map_from_footprints,
    load_map,
    map_summary,
)

__all__ = [
    "DEFAULT_HEIGHT_M",
    "LEVEL_HEIGHT_M",
    "MAX_CLOSING_GAP_M",
    "MIN_AREA_M2",
    "Building",
    "CityMap",
    "Facades",
    "LoadReport",
    "MapLoadError",
    "MapReadOptions",
    "city_map_from_footprints",
    "load_map",
    "map_summary",
]
