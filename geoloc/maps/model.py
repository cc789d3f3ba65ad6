"""What a loaded map is, how a file is read, and the error a bad file raises.

:class:`CityMap` with its :class:`Building` list, :class:`Facades` arrays and :class:`LoadReport`;
how a file is read (:class:`MapReadOptions`); the error :class:`MapLoadError`.

Everything geometric is in the map's local East-North frame (metres, :class:`geoloc.core.geo.LocalFrame`).
Spatial lookups that grow with the map go through lazily built, cached indexes (an STRtree of the
footprints, a cell index of the facades), so that work near one place costs the same on a
500-building map and on a 100,000-building one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

from geoloc.core.geo import LocalFrame
from geoloc.maps.spatial import FacadeIndex

MapProgress = Callable[[int, int], None]
"""A parse's progress callback: ``(elements read, buildings found so far)``, called every
:data:`PROGRESS_EVERY` elements (OSM) or once per layer read (GIS); the caller bounds how often it records it."""
PROGRESS_EVERY = 50_000
"""OSM objects read between two progress calls."""


class MapLoadError(ValueError):
    """The file is not map data we can read, holds no buildings, or its coordinates cannot be placed.

    code: a short machine-readable reason (``invalid_map`` unless more specific, e.g. ``crs_not_lonlat``).
    details: JSON-ready facts behind the message (layers found, coordinate ranges, a guessed CRS).
    """

    def __init__(self, message: str, code: str = "invalid_map", details: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.details = details or {}


DEFAULT_ATTRIBUTES = {"name_attribute": "name", "height_attribute": "height", "levels_attribute": "building:levels"}


@dataclass(frozen=True)
class MapReadOptions:
    """How to read a map file.

    layer: the GIS layer to read (GeoPackage tables, shapefiles in a zip); needed only when a file has
    several polygon layers. name_attribute, height_attribute, levels_attribute: the attribute (GIS field
    or OSM tag) holding a building's name, height (metres; units "m" allowed) and number of storeys.
    crs: the CRS of a GIS file's coordinates (e.g. ``EPSG:3857``), overriding what the file declares
    (as ``ogr2ogr -s_srs`` does); OSM data is always WGS84.
    """

    layer: str | None = None
    name_attribute: str = DEFAULT_ATTRIBUTES["name_attribute"]
    height_attribute: str = DEFAULT_ATTRIBUTES["height_attribute"]
    levels_attribute: str = DEFAULT_ATTRIBUTES["levels_attribute"]
    crs: str | None = None

    def as_dict(self) -> dict[str, str]:
        """The options that differ from the defaults (``{}`` for a plain load), for storage and comparison."""
        defaults = MapReadOptions()
        return {k: v for k, v in asdict(self).items() if v is not None and v != getattr(defaults, k)}

    @classmethod
    def from_dict(cls, values: dict[str, Any] | None) -> MapReadOptions:
        """Options from :meth:`as_dict` output (unknown keys are an error)."""
        return cls(**(values or {}))

    def explicit_attributes(self) -> dict[str, str]:
        """The attribute options set to something other than their default ({option: attribute name})."""
        return {k: v for k, v in self.as_dict().items() if k in DEFAULT_ATTRIBUTES}


@dataclass
class LoadReport:
    """Counts of what was read, repaired and skipped while loading a map, and where it came from.

    format: the detected format (``osm``, ``osm.bz2``, ``osm.gz``, ``pbf``, ``geojson``, ``geojson.gz``,
    ``gpkg``, ``shapefile.zip``, ``fgb``). layer, crs: the GIS layer read and the CRS its coordinates
    were converted from (empty for OSM, which is always WGS84). layer_choice: why that layer was read when the
    file has several polygon layers and none was named (empty otherwise). features_not_polygons: GIS features
    skipped because their geometry is not a polygon (or is empty).
    """

    format: str = ""
    layer: str = ""
    layer_choice: str = ""
    crs: str = ""
    building_ways: int = 0
    building_relations: int = 0
    building_parts_ignored: int = 0
    features_not_polygons: int = 0
    closed_unclosed_ways: int = 0
    skipped_unclosed: int = 0
    skipped_degenerate: int = 0
    repaired_invalid: int = 0
    skipped_incomplete_relations: int = 0
    missing_node_refs: int = 0
    short_facades_dropped: int = 0

    def as_dict(self) -> dict[str, int | str]:
        """The counts as a JSON-ready dict."""
        return asdict(self)


@dataclass
class Building:
    """One building. ``polygon`` is in the map's local frame (metres)."""

    building_id: int
    osm_id: str  # "way/123", "relation/45", a GIS feature's id, or "feature/<fid>"
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
        """Number of facades."""
        return len(self.length_m)


@dataclass
class CityMap:
    """A loaded map: its local frame, buildings, facades and street furniture (all local metres).

    Street names and landmarks (named points: sights, stations, shops...) feed the place search
    (:mod:`geoloc.maps.places`).

    The indexes below (:attr:`footprints`, :attr:`footprint_tree`, :attr:`facade_index`,
    :attr:`bounds_m`) are built on first use and kept with the map.
    """

    frame: LocalFrame
    buildings: list[Building]
    facades: Facades
    building_height_m: np.ndarray  # (B,)
    trees: np.ndarray  # (T, 2) positions of natural=tree nodes
    street_lonlat: np.ndarray  # (N, 2) highway centreline points, lon/lat degrees (see streets)
    street_offsets: np.ndarray  # (S + 1,) polyline s is street_lonlat[offsets[s]:offsets[s + 1]]
    bbox_wgs84: tuple[float, float, float, float]  # min_lat, min_lon, max_lat, max_lon
    report: LoadReport
    source: str = ""
    street_names: list[str] = field(default_factory=list)  # (S,) a street's name tag, "" when unnamed
    landmark_lonlat: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (L, 2) named points, lon/lat
    landmark_names: list[str] = field(default_factory=list)  # (L,) their names

    @cached_property
    def streets(self) -> list[np.ndarray]:
        """Highway centrelines as (N, 2) local polylines (converted on first use: the simulator, the heat map PNG)."""
        if not len(self.street_lonlat):
            return []
        x, y = self.frame.to_local(self.street_lonlat[:, 1], self.street_lonlat[:, 0])
        xy = np.column_stack([x, y])
        bounds = self.street_offsets.tolist()
        return [xy[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]

    @cached_property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(min_x, min_y, max_x, max_y) of the buildings' footprints in the local frame."""
        lo = np.minimum(self.facades.start.min(axis=0), self.facades.end.min(axis=0))
        hi = np.maximum(self.facades.start.max(axis=0), self.facades.end.max(axis=0))
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    @cached_property
    def footprints(self) -> np.ndarray:
        """(B,) object array of the footprints, indexed by building id."""
        out = np.empty(len(self.buildings), dtype=object)
        out[:] = [b.polygon for b in self.buildings]
        return out

    @cached_property
    def footprint_tree(self) -> shapely.STRtree:
        """STRtree of :attr:`footprints`; its query results are building ids."""
        return shapely.STRtree(self.footprints)

    @cached_property
    def facade_index(self) -> FacadeIndex:
        """Cell index of the facades for range queries (used by the ray casters)."""
        return FacadeIndex(self.facades)

    @cached_property
    def known_building_height_m(self) -> np.ndarray:
        """(B,) read-only building heights where the map states them (``height`` or ``building:levels``).

        NaN where the height is the default; cached, since the likelihood's skyline term asks for it on every
        call.
        """
        known = np.array([b.height_source != "default" for b in self.buildings], dtype=bool)
        heights = np.where(known, np.asarray(self.building_height_m, dtype=float), np.nan)
        heights.flags.writeable = False
        return heights

    @cached_property
    def building_union(self) -> BaseGeometry:
        """Union of all footprints (cached).

        Costs time and memory in the map's size: prefer :meth:`inside_buildings` and
        :meth:`buildings_near` for local questions.
        """
        return unary_union(self.footprints)

    def inside_buildings(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) local points -> (N,) bool, True where a point lies inside a footprint (not on its edge)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        inside = np.zeros(len(xy), dtype=bool)
        if len(xy) and len(self.buildings):
            point_index, _ = self.footprint_tree.query(shapely.points(xy), predicate="within")
            inside[point_index] = True
        return inside

    def buildings_near(self, bounds_m: tuple[float, float, float, float]) -> np.ndarray:
        """Sorted ids of the buildings whose footprint intersects the box (min_x, min_y, max_x, max_y)."""
        return np.sort(self.footprint_tree.query(shapely.box(*bounds_m), predicate="intersects"))
