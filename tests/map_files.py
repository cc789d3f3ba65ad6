"""Map files of every accepted format, written at test time from the shared Helsinki extract.

Written with the same libraries the service reads them with (pyogrio/GDAL, shapely, pyproj); never
checked in.

:func:`write_map_files` writes into a folder and returns :class:`MapFiles`: the good files (each
with the expected building count and read options) and the malformed ones (with the error code
each must get).
"""

from __future__ import annotations

import gzip
import json
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyogrio.raw
import shapely
from pyproj import Transformer

from contracts.settings import shared_path
from geoloc.maps import CityMap, load_map

HELSINKI_BUILDINGS = 464
BERLIN_BUILDINGS = 1993
FINNISH_GRID = "EPSG:3067"  # ETRS-TM35FIN, the national grid of Finland's municipal data
UTM_35N = "EPSG:32635"


@dataclass
class GoodFile:
    """A map file that must load: its path, read options (form fields), expected building count."""

    path: Path
    buildings: int
    options: dict[str, str] = field(default_factory=dict)
    source_format: str = ""


@dataclass
class BadFile:
    """A malformed map file (or a bad choice of options) and the error code it must get."""

    path: Path
    code: str
    fragment: str
    options: dict[str, str] = field(default_factory=dict)


BAD_CASES = (
    "mercator geojson without crs",
    "gpkg: several polygon layers, none named",
    "gpkg: a layer name that does not exist",
    "gpkg: an attribute that does not exist",
    "gpkg without polygons",
    "truncated osm.gz",
    "truncated geojson.gz",
    "zip without a shapefile",
    "mixed crs: degrees and metres, no crs",
    "mixed crs: degrees in a 3857 layer",
    "osm with a crs option",
)
"""The malformed variants :func:`write_map_files` makes (the keys of ``MapFiles.bad``), for parametrizing."""


@dataclass
class MapFiles:
    helsinki: CityMap
    good: dict[str, GoodFile]
    bad: dict[str, BadFile]


def helsinki_wgs84(city: CityMap) -> np.ndarray:
    """The footprints of a loaded map as lon/lat geometries (its local frame undone)."""

    def to_lonlat(xy: np.ndarray) -> np.ndarray:
        lat, lon = city.frame.to_wgs84(xy[:, 0], xy[:, 1])
        return np.column_stack([lon, lat])

    return np.asarray(shapely.transform(city.footprints, to_lonlat))


def reproject(geoms: np.ndarray, crs: str) -> np.ndarray:
    """Lon/lat geometries to ``crs`` (x = easting)."""
    transformer = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    return np.asarray(shapely.transform(geoms, lambda xy: np.column_stack(transformer.transform(xy[:, 0], xy[:, 1]))))


def _attributes(city: CityMap, levels: str = "building:levels") -> dict[str, np.ndarray]:
    """osm_id, name, height (m, NaN where untagged) and storeys (NaN where untagged, column ``levels``)."""
    ids = np.array([b.osm_id for b in city.buildings], dtype=object)
    names = np.array([b.name for b in city.buildings], dtype=object)
    height = np.array([float(b.tags["height"].split()[0]) if b.height_source == "height" else np.nan
                       for b in city.buildings])  # fmt: skip
    storeys = np.array([b.height_m / 3.0 if b.height_source == "levels" else np.nan for b in city.buildings])
    return {"osm_id": ids, "name": names, "height": height, levels: storeys}


def write_polygons(path: Path, geoms: np.ndarray, crs: str | None, driver: str, columns: dict[str, np.ndarray],
           layer: str | None = None, **kwargs: Any) -> Path:  # fmt: skip
    """Write polygons with attribute columns; GeoJSON keeps each feature's type, the others get MultiPolygons."""
    geometry_type = "Unknown" if driver == "GeoJSON" else "MultiPolygon"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # GDAL's notes on files written without a CRS, on purpose here
        pyogrio.raw.write(
            str(path),
            shapely.to_wkb(geoms),
            list(columns.values()),
            fields=list(columns),
            crs=crs,
            driver=driver,
            geometry_type=geometry_type,
            promote_to_multi=driver != "GeoJSON",
            layer=layer,
            **kwargs,
        )
    return path


def write_map_files(folder: Path) -> MapFiles:
    """Write every test map file into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    city = load_map(shared_path("data", "osm", "helsinki.osm.pbf"))
    lonlat = helsinki_wgs84(city)
    attributes = _attributes(city)
    n = len(lonlat)
    good: dict[str, GoodFile] = {}
    bad: dict[str, BadFile] = {}

    # GeoJSON, RFC 7946: WGS84 lon/lat and no CRS member.
    wgs84 = write_polygons(folder / "helsinki.geojson", lonlat, None, "GeoJSON", attributes, RFC7946="YES")
    good["geojson"] = GoodFile(wgs84, n, source_format="geojson")
    gz = folder / "helsinki.geojson.gz"
    gz.write_bytes(gzip.compress(wgs84.read_bytes()))
    good["geojson.gz"] = GoodFile(gz, n, source_format="geojson.gz")

    # The same footprints in Web Mercator, as a municipal layer would give them: with a legacy CRS member ...
    mercator = reproject(lonlat, "EPSG:3857")
    with_crs = write_polygons(folder / "helsinki_3857.geojson", mercator, "EPSG:3857", "GeoJSON", attributes)
    assert b'"crs"' in with_crs.read_bytes()[:400], "GDAL wrote the legacy crs member"
    good["geojson_3857"] = GoodFile(with_crs, n, source_format="geojson")
    # ... and without one (RFC 7946 says lon/lat: must be refused, or read with the crs form field).
    data = json.loads(with_crs.read_text())
    data.pop("crs")
    no_crs = folder / "helsinki_3857_no_crs.geojson"
    no_crs.write_text(json.dumps(data))
    good["geojson_3857_crs_option"] = GoodFile(no_crs, n, {"crs": "EPSG:3857"}, "geojson")
    bad["mercator geojson without crs"] = BadFile(no_crs, "crs_not_lonlat", "EPSG:3857 Web Mercator")

    # GeoPackage in the Finnish national grid, with Finnish attribute names, a point layer and a second
    # polygon layer (so the buildings layer must be named).
    gpkg = folder / "helsinki.gpkg"
    finnish = {"osm_id": attributes["osm_id"], "NIMI": attributes["name"], "KORKEUS": attributes["height"],
               "KERROKSIA": attributes["building:levels"]}  # fmt: skip
    write_polygons(gpkg, reproject(lonlat, FINNISH_GRID), FINNISH_GRID, "GPKG", finnish, layer="rakennukset")
    centroids = shapely.centroid(reproject(lonlat, FINNISH_GRID))
    _write_points(gpkg, centroids, FINNISH_GRID, "osoitteet", append=True)
    blocks = shapely.buffer(centroids[:5], 30.0)
    write_polygons(gpkg, blocks, FINNISH_GRID, "GPKG", {"NIMI": np.array(["k"] * 5, dtype=object)}, layer="korttelit",
           append=True)  # fmt: skip
    gpkg_options = {"layer": "rakennukset", "name_attribute": "NIMI", "height_attribute": "KORKEUS",
                    "levels_attribute": "KERROKSIA"}  # fmt: skip
    good["gpkg"] = GoodFile(gpkg, n, gpkg_options, "gpkg")
    bad["gpkg: several polygon layers, none named"] = BadFile(gpkg, "layer_required", "korttelit")
    bad["gpkg: a layer name that does not exist"] = BadFile(gpkg, "layer_not_found", "rakennukset",
                                                             {"layer": "buildings"})  # fmt: skip
    bad["gpkg: an attribute that does not exist"] = BadFile(
        gpkg, "attribute_not_found", "KORKEUS", {"layer": "rakennukset", "height_attribute": "korkeus_m"}
    )
    # Several polygon layers, none named in the form: the one named "buildings" is read, or the only one
    # with a "building" attribute (each beside a layer of city blocks and one of address points).
    for key, layer, columns in (
        ("gpkg_buildings_layer", "buildings", attributes),
        ("gpkg_building_attribute", "talot", {**attributes, "building": np.array(["yes"] * n, dtype=object)}),
    ):
        path = write_polygons(folder / f"{key}.gpkg", lonlat, "EPSG:4326", "GPKG", columns, layer=layer)
        write_polygons(path, shapely.buffer(shapely.centroid(lonlat[:5]), 0.0003), "EPSG:4326", "GPKG",
               {"name": np.array(["k"] * 5, dtype=object)}, layer="korttelit", append=True)  # fmt: skip
        _write_points(path, shapely.centroid(lonlat), "EPSG:4326", "osoitteet", append=True)
        good[key] = GoodFile(path, n, source_format="gpkg")
    points_only = _write_points(folder / "addresses.gpkg", centroids, FINNISH_GRID, "osoitteet")
    bad["gpkg without polygons"] = BadFile(points_only, "no_polygon_layer", "osoitteet (Point)")

    # Zipped Shapefile in UTM 35N, in a sub-folder of the zip as people zip them (field names of 10 chars).
    shp_dir = folder / "shp"
    shp_dir.mkdir(exist_ok=True)
    write_polygons(shp_dir / "buildings.shp", reproject(lonlat, UTM_35N), UTM_35N, "ESRI Shapefile",
           _attributes(city, levels="levels"))  # fmt: skip
    shp_zip = folder / "helsinki_shp.zip"
    with zipfile.ZipFile(shp_zip, "w", zipfile.ZIP_DEFLATED) as archive:
        for part in sorted(shp_dir.iterdir()):
            archive.write(part, f"helsinki/{part.name}")
    good["shapefile.zip"] = GoodFile(shp_zip, n, {"levels_attribute": "levels"}, "shapefile.zip")

    # FlatGeobuf in WGS84.
    fgb = write_polygons(folder / "helsinki.fgb", lonlat, "EPSG:4326", "FlatGeobuf", attributes)
    good["fgb"] = GoodFile(fgb, n, source_format="fgb")

    # OSM XML, gzipped (an Overpass download).
    good["osm.gz"] = GoodFile(shared_path("data", "berlin", "berlin_mitte.osm.gz"), BERLIN_BUILDINGS,
                              source_format="osm.gz")  # fmt: skip

    # --- malformed ---
    truncated = folder / "truncated.osm.gz"
    berlin = shared_path("data", "berlin", "berlin_mitte.osm.gz").read_bytes()
    truncated.write_bytes(berlin[: len(berlin) // 2])
    bad["truncated osm.gz"] = BadFile(truncated, "invalid_map", "gzip stream is truncated")
    truncated_json = folder / "truncated.geojson.gz"
    truncated_json.write_bytes(gz.read_bytes()[: gz.stat().st_size // 2])
    bad["truncated geojson.gz"] = BadFile(truncated_json, "invalid_map", "gzip stream is truncated")
    no_shp = folder / "no_shapefile.zip"
    with zipfile.ZipFile(no_shp, "w") as archive:
        archive.writestr("README.txt", "the buildings are in another file")
        archive.write(wgs84, "helsinki.json")
    bad["zip without a shapefile"] = BadFile(no_shp, "invalid_map", "zip archive without a shapefile")
    bad["mixed crs: degrees and metres, no crs"] = BadFile(
        _mixed_geojson(folder / "mixed.geojson", lonlat, mercator, declare_mercator=False), "mixed_crs", "mix"
    )
    bad["mixed crs: degrees in a 3857 layer"] = BadFile(
        _mixed_geojson(folder / "mixed_3857.geojson", lonlat, mercator, declare_mercator=True), "mixed_crs", "mix"
    )
    bad["osm with a crs option"] = BadFile(good["osm.gz"].path, "invalid_map", "always WGS84", {"crs": "EPSG:3857"})
    return MapFiles(city, good, bad)


def _write_points(path: Path, points: np.ndarray, crs: str, layer: str, append: bool = False) -> Path:
    pyogrio.raw.write(str(path), shapely.to_wkb(points), [np.arange(len(points))], fields=["nro"], crs=crs,
                      driver="GPKG", geometry_type="Point", layer=layer, append=append)  # fmt: skip
    return path


def _mixed_geojson(path: Path, lonlat: np.ndarray, mercator: np.ndarray, declare_mercator: bool) -> Path:
    """Half the features in lon/lat degrees, half in Web Mercator metres, in one FeatureCollection."""
    half = len(lonlat) // 2
    geoms = list(lonlat[:half]) + list(mercator[half:])
    features = [{"type": "Feature", "properties": {"n": i}, "geometry": json.loads(shapely.to_geojson(g))}
                for i, g in enumerate(geoms)]  # fmt: skip
    data: dict[str, Any] = {"type": "FeatureCollection", "features": features}
    if declare_mercator:
        data["crs"] = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::3857"}}
    path.write_text(json.dumps(data))
    return path
