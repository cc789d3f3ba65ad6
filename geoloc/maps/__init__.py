"""Maps: buildings and their facades from the files people have.

Accepted (told from the content, not the name):

- OpenStreetMap: XML (``.osm``, ``.osm.bz2``, ``.osm.gz``) and ``.osm.pbf`` (:mod:`geoloc.maps.osm_reader`);
- GIS files, read with pyogrio/GDAL (:mod:`geoloc.maps.gis_reader`): GeoJSON (``.geojson``,
  ``.geojson.gz``), GeoPackage, FlatGeobuf and zipped Shapefiles, in any CRS they declare
  (:mod:`geoloc.maps.crs`).

Modules, one job each: :mod:`~geoloc.maps.sniff` (which format), the two readers (file ->
:class:`~geoloc.maps.build.RawMap` in lon/lat), :mod:`~geoloc.maps.build` (RawMap -> :class:`CityMap`:
local frame, repairs, facades), :mod:`~geoloc.maps.model` (the types, with cached spatial indexes),
:mod:`~geoloc.maps.spatial` (the facade cell index), :mod:`~geoloc.maps.store` (a loaded map as one
binary file) and :mod:`~geoloc.maps.load` (the entry points).
"""

from geoloc.maps.build import DEFAULT_HEIGHT_M, LEVEL_HEIGHT_M, MAX_CLOSING_GAP_M, MIN_AREA_M2, parse_height
from geoloc.maps.load import city_map_from_footprints, file_sha256, load_map, load_map_cached, map_summary
from geoloc.maps.model import Building, CityMap, Facades, LoadReport, MapLoadError, MapReadOptions
from geoloc.maps.spatial import FacadeIndex
from geoloc.maps.store import map_cache_dir, map_cache_path, read_city_map, remove_cached_map, save_city_map

__all__ = [
    "DEFAULT_HEIGHT_M",
    "LEVEL_HEIGHT_M",
    "MAX_CLOSING_GAP_M",
    "MIN_AREA_M2",
    "Building",
    "CityMap",
    "FacadeIndex",
    "Facades",
    "LoadReport",
    "MapLoadError",
    "MapReadOptions",
    "city_map_from_footprints",
    "file_sha256",
    "load_map",
    "load_map_cached",
    "map_cache_dir",
    "map_cache_path",
    "map_summary",
    "parse_height",
    "read_city_map",
    "remove_cached_map",
    "save_city_map",
]
