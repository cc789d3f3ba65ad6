"""GIS files (GeoJSON plain/.gz, GeoPackage, FlatGeobuf, zipped Shapefile) -> :class:`RawMap`, with pyogrio.

One layer is read: the one named by ``MapReadOptions.layer``, else the file's only polygon layer; of several
polygon layers and no name, the only one named ``buildings`` (or ``building``), else the only one with a
``building`` attribute, saying so in the report's ``layer_choice``; else the file is refused, listing them.
Only polygon features are buildings (others are counted in ``features_not_polygons``); when the layer has a
``building`` attribute that some feature fills, features with no value or ``no`` there are left out, as in
OSM. Names, heights and storeys come from the attributes named in the options (a unique case-insensitive match counts,
so ``NAME`` serves for ``name``; an attribute named explicitly that the layer lacks is refused).
A feature's id is its ``@id``, ``osm_id`` or ``id`` attribute, else ``feature/<FID>``. Rings that
are not closed are closed (counted in ``closed_unclosed_ways``). Coordinates are converted to
lon/lat by :func:`geoloc.maps.crs.to_lonlat`.
"""

from __future__ import annotations

import gzip
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyogrio
import pyogrio.raw
import shapely
from pyproj import CRS
from pyproj.exceptions import CRSError

from geoloc.maps.build import RawMap
from geoloc.maps.crs import parse_crs, to_lonlat
from geoloc.maps.model import LoadReport, MapLoadError, MapReadOptions
from geoloc.maps.sniff import FORMAT_NAMES, check_compressed_stream, zip_member_names

_ID_ATTRIBUTES = ("@id", "osm_id", "id")
_EXTRA_ATTRIBUTES = ("building", "addr:street", "addr:housenumber", "amenity")
_CRS_LOOKAHEAD_BYTES = 1 << 16
_SINGLE_LAYER_FORMATS = ("geojson", "geojson.gz", "fgb")
BUILDINGS_LAYER_NAMES = ("buildings", "building")
_POLYGON_TYPES = (shapely.GeometryType.POLYGON, shapely.GeometryType.MULTIPOLYGON)


@dataclass
class Layer:
    """A layer of a GIS file: its name, GDAL geometry type, and where GDAL reads it."""

    name: str
    geometry_type: str | None
    gdal_path: str
    gdal_layer: str | int
    chosen_by: str = ""  # why this layer was read when the file has several and none was named

    @property
    def polygonal(self) -> bool:
        """Whether the layer's declared geometry type is a polygon or surface type."""
        kind = (self.geometry_type or "").lower()
        return "polygon" in kind or "surface" in kind

    @property
    def maybe_polygonal(self) -> bool:
        """Polygonal, or of a generic type (``Unknown``, ``Geometry``) that may hold polygons."""
        kind = (self.geometry_type or "").lower()
        return self.polygonal or kind in ("unknown", "geometry", "geometrycollection", "unknown (any)")

    def describe(self) -> str:
        """The layer's name and geometry type, for messages."""
        return f"{self.name or '(unnamed)'} ({self.geometry_type or 'no geometry'})"


def read_gis(path: Path, kind: str, options: MapReadOptions) -> RawMap:
    """Buildings of the chosen polygon layer of a GIS file of format ``kind``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # GDAL's notes on file names, unclosed rings
            layer = choose_layer(list_layers(path, kind), options.layer, path.name)
            return _read_layer(path, kind, layer, options)
    except pyogrio.errors.DataSourceError as exc:
        check_compressed_stream(path, kind)
        what = "not valid GeoJSON" if kind.startswith("geojson") else f"cannot read the {FORMAT_NAMES[kind]}"
        raise MapLoadError(f"{path.name}: {what}: {_gdal_message(exc)}") from exc
    except (
        pyogrio.errors.DataLayerError,
        pyogrio.errors.FieldError,
        pyogrio.errors.GeometryError,
        pyogrio.errors.FeatureError,
        pyogrio.errors.CRSError,
    ) as exc:
        check_compressed_stream(path, kind)
        raise MapLoadError(f"{path.name}: cannot read the {FORMAT_NAMES[kind]}: {_gdal_message(exc)}") from exc


def list_layers(path: Path, kind: str) -> list[Layer]:
    """The layers of a GIS file (every shapefile of a zip is a layer, named after its file)."""
    if kind == "shapefile.zip":
        shapefiles = [name for name in zip_member_names(path) if name.lower().endswith(".shp")]
        stems = [Path(name).stem for name in shapefiles]
        layers = []
        for member, stem in zip(shapefiles, stems, strict=True):
            name = stem if stems.count(stem) == 1 else member[: -len(".shp")]
            gdal_path = f"/vsizip/{{{path.resolve()}}}/{member}"
            layers.append(Layer(name, pyogrio.read_info(gdal_path)["geometry_type"], gdal_path, 0))
        return layers
    gdal_path = f"/vsigzip/{path.resolve()}" if kind.endswith(".gz") else str(path)
    layers = [Layer(str(name), kind_, gdal_path, str(name)) for name, kind_ in pyogrio.list_layers(gdal_path)]
    for layer in layers:
        if kind in _SINGLE_LAYER_FORMATS and layer.name in (path.stem, path.name.split(".")[0]):
            layer.name = ""  # GDAL named it after the file: the file itself names no layer
    return layers


def choose_layer(layers: list[Layer], wanted: str | None, file_name: str) -> Layer:
    """The layer named ``wanted`` (exact, else a unique case-insensitive match), or the only polygon layer."""
    listing = ", ".join(layer.describe() for layer in layers) or "none"
    details = {"layers": [{"name": layer.name, "geometry_type": layer.geometry_type} for layer in layers]}
    if wanted is not None:
        match = [layer for layer in layers if layer.name == wanted] or [
            layer for layer in layers if layer.name.lower() == wanted.lower()
        ]
        if len(match) != 1:
            raise MapLoadError(
                f"{file_name}: no layer named {wanted!r}; the file's layers: {listing}",
                code="layer_not_found",
                details=details,
            )
        if not match[0].maybe_polygonal:
            raise MapLoadError(
                f"{file_name}: layer {match[0].name!r} holds {match[0].geometry_type or 'no'} geometries, not "
                f"building polygons; the file's layers: {listing}",
                code="no_polygon_layer",
                details=details,
            )
        return match[0]
    candidates = [layer for layer in layers if layer.polygonal] or [layer for layer in layers if layer.maybe_polygonal]
    if not candidates:
        raise MapLoadError(
            f"{file_name}: no polygon layer (buildings are polygons); the file's layers: {listing}",
            code="no_polygon_layer",
            details=details,
        )
    if len(candidates) > 1:
        names = ", ".join(repr(layer.name) for layer in candidates)
        chosen = _buildings_layer(candidates)
        if chosen is not None:
            chosen.chosen_by = f"{len(candidates)} polygon layers ({names}): read {chosen.name!r}, {chosen.chosen_by}"
            return chosen
        raise MapLoadError(
            f"{file_name}: {len(candidates)} polygon layers ({names}); choose one with the layer option "
            "(form field layer, geoloc map info --layer)",
            code="layer_required",
            details=details,
        )
    return candidates[0]


def _buildings_layer(candidates: list[Layer]) -> Layer | None:
    """Of several polygon layers, the one that says it holds the buildings, or None when none or several do.

    The only layer named ``buildings`` (or ``building``, any case), else the only one with a ``building``
    attribute (any case); its ``chosen_by`` says which rule picked it.
    """
    named = [layer for layer in candidates if layer.name.lower() in BUILDINGS_LAYER_NAMES]
    if len(named) == 1:
        named[0].chosen_by = f"the only one named {named[0].name!r}"
        return named[0]
    if named:
        return None
    with_attribute = [
        layer
        for layer in candidates
        if "building" in (str(f).lower() for f in pyogrio.read_info(layer.gdal_path, layer=layer.gdal_layer)["fields"])
    ]
    if len(with_attribute) == 1:
        with_attribute[0].chosen_by = "the only one with a 'building' attribute"
        return with_attribute[0]
    return None


def _read_layer(path: Path, kind: str, layer: Layer, options: MapReadOptions) -> RawMap:
    what = f"{path.name}, layer {layer.name!r}" if layer.name else path.name
    fields = [str(f) for f in pyogrio.read_info(layer.gdal_path, layer=layer.gdal_layer)["fields"]]
    columns = _attribute_columns(fields, options, what)
    meta, fids, wkb, values = pyogrio.raw.read(
        layer.gdal_path,
        layer=layer.gdal_layer,
        columns=sorted(set(columns.values())),
        return_fids=True,
        force_2d=True,
    )
    report = LoadReport(format=kind, layer=layer.name, layer_choice=layer.chosen_by)
    by_field = dict(zip(meta["fields"], values, strict=True))
    geoms = _polygons(wkb, report)
    attributes = {attribute: by_field[field] for attribute, field in columns.items()}
    keep = ~shapely.is_missing(geoms)
    report.features_not_polygons += int((~keep).sum())
    building = attributes.get("building")
    if building is not None:
        filled = np.array([_text(v) is not None for v in building], dtype=bool)
        if filled.any():
            keep = keep & np.array([_text(v) not in (None, "no") for v in building], dtype=bool)
    index = np.flatnonzero(keep)
    if not len(index):
        raise MapLoadError(
            f"{what}: no buildings found ({len(geoms)} features, none a building polygon)",
            details={"features": int(len(geoms))},
        )
    geoms = geoms[index]

    declared = meta.get("crs") if not kind.startswith("geojson") or _geojson_declares_crs(path, kind) else None
    crs = _layer_crs(declared, options, what)
    coords, owner = shapely.get_coordinates(geoms, return_index=True)
    lonlat, report.crs = to_lonlat(coords, owner, crs, what)
    raw = RawMap(kind, report)
    raw.feature_geoms = shapely.set_coordinates(geoms.copy(), lonlat)
    raw.feature_tags = [
        {attribute: text for attribute, column in attributes.items() if (text := _text(column[i])) is not None}
        for i in index.tolist()
    ]
    raw.feature_ids = [
        next((tags[a] for a in _ID_ATTRIBUTES if a in tags), f"feature/{int(fids[i])}")
        for tags, i in zip(raw.feature_tags, index.tolist(), strict=True)
    ]
    report.building_ways = len(index)
    return raw


def _attribute_columns(fields: list[str], options: MapReadOptions, what: str) -> dict[str, str]:
    """{attribute name used in tags: the layer's field that holds it} for every attribute we read."""
    lower: dict[str, list[str]] = {}
    for name in fields:
        lower.setdefault(name.lower(), []).append(name)

    def resolve(attribute: str) -> str | None:
        if attribute in fields:
            return attribute
        matches = lower.get(attribute.lower(), [])
        return matches[0] if len(matches) == 1 else None

    columns: dict[str, str] = {}
    for option, attribute in options.explicit_attributes().items():
        if resolve(attribute) is None:
            raise MapLoadError(
                f"{what}: no attribute {attribute!r} (asked for as {option}); the layer's attributes: "
                f"{', '.join(fields) or 'none'}",
                code="attribute_not_found",
                details={"attributes": fields},
            )
    wanted = (options.name_attribute, options.height_attribute, options.levels_attribute)
    for attribute in (*wanted, *_EXTRA_ATTRIBUTES, *_ID_ATTRIBUTES):
        field = resolve(attribute)
        if field is not None:
            columns.setdefault(attribute, field)
    return columns


def _polygons(wkb: np.ndarray, report: LoadReport) -> np.ndarray:
    """Polygon/MultiPolygon geometries from WKB (None for anything else); unclosed rings closed and counted."""
    geoms = shapely.from_wkb(wkb, on_invalid="ignore")
    broken = shapely.is_missing(geoms) & np.array([w is not None for w in wkb], dtype=bool)
    if broken.any():
        fixed = shapely.from_wkb(wkb[broken], on_invalid="fix")
        report.closed_unclosed_ways += int((~shapely.is_missing(fixed)).sum())
        geoms[broken] = fixed
    polygonal = np.isin(shapely.get_type_id(geoms), _POLYGON_TYPES) & ~shapely.is_empty(geoms)
    geoms[~polygonal] = None
    return np.asarray(geoms)


def _layer_crs(declared: str | None, options: MapReadOptions, what: str) -> CRS | None:
    if options.crs:
        return parse_crs(options.crs)
    if not declared:
        return None
    try:
        return CRS.from_user_input(declared)
    except CRSError as exc:
        raise MapLoadError(
            f"{what}: the file declares a CRS that cannot be read ({exc}); name it with the form field crs",
            code="invalid_crs",
        ) from exc


def _geojson_declares_crs(path: Path, kind: str) -> bool:
    """Whether a GeoJSON file has a (legacy) ``crs`` member near its start, where writers put it.

    GDAL reports EPSG:4326 either way; this tells "declared" from "RFC 7946 default" for messages.
    """
    opener = gzip.open if kind.endswith(".gz") else open
    with opener(path, "rb") as f:
        return b'"crs"' in f.read(_CRS_LOOKAHEAD_BYTES)


def _text(value: Any) -> str | None:
    """An attribute value as tag text (None for null/NaN; 3.0 -> "3")."""
    if value is None:
        return None
    if isinstance(value, float | np.floating):
        number = float(value)
        if math.isnan(number):
            return None
        return str(int(number)) if number.is_integer() else repr(number)
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    text = str(value).strip()
    return text or None


def _gdal_message(exc: Exception) -> str:
    """GDAL's message without the source-file location it appends."""
    return str(exc).split("; In file ")[0].strip()
