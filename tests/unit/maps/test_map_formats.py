"""Every accepted map format, read from real files written at test time from the shared OSM data.

The files are ``tests/map_files.py``'s: building counts, footprints to 0.5 m against the source whatever
the CRS, names and heights through configurable attributes, and a clear :class:`MapLoadError` for every
malformed variant.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from geoloc.core.geo import LocalFrame
from geoloc.maps import CityMap, MapLoadError, MapReadOptions, load_map
from geoloc.maps.crs import guess_crs
from tests.map_files import BAD_CASES, BERLIN_BUILDINGS, MapFiles, helsinki_wgs84, write_map_files, write_polygons


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> MapFiles:
    return write_map_files(tmp_path_factory.mktemp("map_files"))


def _same_order(city: CityMap, reference: CityMap) -> np.ndarray:
    """Index into ``city.buildings`` of each reference building, matched by OSM id.

    GIS files carry it as an attribute; FlatGeobuf stores features in its spatial index's order.
    """
    index = {b.osm_id: i for i, b in enumerate(city.buildings)}
    return np.array([index[b.osm_id] for b in reference.buildings])


def _max_offset_m(city: CityMap, reference: CityMap) -> float:
    """Largest Hausdorff distance (m) between the buildings of ``city`` and those of ``reference``.

    Each building is compared with the one with the same OSM id, both placed in the reference's local
    frame through WGS84.
    """
    frame: LocalFrame = reference.frame

    def to_reference_frame(lonlat: np.ndarray) -> np.ndarray:
        x, y = frame.to_local(lonlat[:, 1], lonlat[:, 0])
        return np.column_stack([x, y])

    placed = shapely.transform(helsinki_wgs84(city), to_reference_frame)[_same_order(city, reference)]
    return float(shapely.hausdorff_distance(placed, reference.footprints).max())


GIS_FORMATS = [
    "geojson",
    "geojson.gz",
    "geojson_3857",
    "geojson_3857_crs_option",
    "gpkg",
    "gpkg_buildings_layer",
    "gpkg_building_attribute",
    "shapefile.zip",
    "fgb",
]


@pytest.mark.parametrize("name", GIS_FORMATS)
def test_gis_file_loads_every_footprint_where_it_belongs(files: MapFiles, name: str) -> None:
    good = files.good[name]
    city = load_map(good.path, MapReadOptions(**good.options))
    assert len(city.buildings) == good.buildings
    assert city.report.format == good.source_format
    assert _max_offset_m(city, files.helsinki) < 0.5
    # Attributes under their configured names: every id, name and height comes through.
    same = [city.buildings[i] for i in _same_order(city, files.helsinki)]
    assert [b.name for b in same] == [b.name for b in files.helsinki.buildings]
    assert np.allclose([b.height_m for b in same], files.helsinki.building_height_m, atol=1e-6)
    assert [b.height_source for b in same] == [b.height_source for b in files.helsinki.buildings]
    assert len(city.facades) == pytest.approx(len(files.helsinki.facades), abs=len(files.helsinki.facades) * 0.01)


def test_mercator_geojson_reads_as_its_wgs84_twin(files: MapFiles) -> None:
    twin = load_map(files.good["geojson"].path)
    mercator = load_map(files.good["geojson_3857"].path)
    assert mercator.report.crs == "EPSG:3857" and twin.report.crs.startswith("none declared")
    assert len(mercator.buildings) == len(twin.buildings)
    assert _max_offset_m(mercator, twin) < 0.5


def test_crs_option_overrides_what_the_file_declares(files: MapFiles) -> None:
    declared_wrongly = load_map(files.good["geojson_3857_crs_option"].path, MapReadOptions(crs="3857"))
    assert declared_wrongly.report.crs == "EPSG:3857"
    with pytest.raises(MapLoadError, match="unknown CRS") as error:
        load_map(files.good["geojson"].path, MapReadOptions(crs="EPSG:99999999"))
    assert error.value.code == "invalid_crs"


def test_gpkg_layer_and_attributes_are_chosen_by_name(files: MapFiles) -> None:
    good = files.good["gpkg"]
    city = load_map(good.path, MapReadOptions(**good.options))
    assert city.report.layer == "rakennukset" and city.report.crs == "EPSG:3067"
    # Without the attribute names, the Finnish fields are not read: no names, default heights.
    plain = load_map(good.path, MapReadOptions(layer="rakennukset"))
    assert [b.osm_id for b in plain.buildings] == [b.osm_id for b in files.helsinki.buildings]
    assert not any(b.name for b in plain.buildings)
    assert {b.height_source for b in plain.buildings} == {"default"}
    # The other polygon layer is a layer like any other.
    blocks = load_map(good.path, MapReadOptions(layer="KORTTELIT"))  # a unique case-insensitive match counts
    assert len(blocks.buildings) == 5 and blocks.report.layer == "korttelit"


@pytest.mark.parametrize(
    ("name", "layer", "because"),
    [
        ("gpkg_buildings_layer", "buildings", "the only one named 'buildings'"),
        ("gpkg_building_attribute", "talot", "the only one with a 'building' attribute"),
    ],
)
def test_of_several_polygon_layers_the_buildings_layer_is_read_and_the_report_says_so(
    files: MapFiles, name: str, layer: str, because: str
) -> None:
    city = load_map(files.good[name].path)
    assert city.report.layer == layer
    choice = city.report.layer_choice
    assert choice.startswith("2 polygon layers (") and "'korttelit'" in choice
    assert choice.endswith(f"read {layer!r}, {because}")
    named = load_map(files.good[name].path, MapReadOptions(layer="korttelit"))  # a named layer still wins
    assert named.report.layer == "korttelit" and named.report.layer_choice == "" and len(named.buildings) == 5


def test_several_layers_that_say_buildings_are_still_refused(files: MapFiles, tmp_path: Path) -> None:
    with pytest.raises(MapLoadError) as error:
        load_map(files.good["gpkg"].path)  # rakennukset and korttelit: neither says it holds buildings
    assert error.value.code == "layer_required"
    both = tmp_path / "both.gpkg"
    lonlat = helsinki_wgs84(files.helsinki)[:3]
    for layer in ("buildings", "building"):
        write_polygons(both, lonlat, "EPSG:4326", "GPKG", {"name": np.array(["b"] * 3, dtype=object)}, layer=layer,
                       append=both.exists())  # fmt: skip
    with pytest.raises(MapLoadError, match="2 polygon layers") as error:
        load_map(both)
    assert error.value.code == "layer_required"


def test_berlin_overpass_download_loads_gzipped(files: MapFiles, tmp_path: Path) -> None:
    import gzip

    city = load_map(files.good["osm.gz"].path)
    assert len(city.buildings) == BERLIN_BUILDINGS and city.report.format == "osm.gz"
    # Its multipolygon relations come without their member ways: skipped and counted, not fatal.
    assert city.report.building_relations == city.report.skipped_incomplete_relations > 0
    plain = tmp_path / "berlin.osm"
    plain.write_bytes(gzip.decompress(files.good["osm.gz"].path.read_bytes()))
    same = load_map(plain)
    assert [b.osm_id for b in same.buildings] == [b.osm_id for b in city.buildings]
    assert np.array_equal(same.facades.start, city.facades.start)


@pytest.mark.parametrize("case", BAD_CASES)
def test_malformed_map_files_raise_a_clear_error(files: MapFiles, case: str) -> None:
    bad = files.bad[case]
    with pytest.raises(MapLoadError) as error:
        load_map(bad.path, MapReadOptions(**bad.options))
    assert error.value.code == bad.code, str(error.value)
    assert bad.fragment in str(error.value)
    assert bad.path.name in str(error.value)


def test_web_mercator_guess_places_the_data() -> None:
    phrase, details = guess_crs(np.array([[2_776_000.0, 8_438_000.0], [2_777_000.0, 8_439_000.0]]))
    assert "EPSG:3857" in phrase
    assert details["if_epsg_3857"] == pytest.approx({"lat": 60.168, "lon": 24.941}, abs=0.01)
    phrase, details = guess_crs(np.array([[60.17, 124.94], [60.18, 124.95]]))
    assert details["guess"] == "swapped_lat_lon"
    phrase, details = guess_crs(np.array([[385_000.0, 6_672_000.0], [386_000.0, 6_673_000.0]]))
    assert "UTM" in phrase  # Helsinki in ETRS-TM35FIN / UTM 35N coordinates


def test_buildings_spread_over_a_continent_are_refused(tmp_path: Path) -> None:
    import json

    squares = [shapely.box(lon, 60.0, lon + 0.001, 60.001) for lon in (5.0, 25.0)]
    features = [{"type": "Feature", "properties": {}, "geometry": json.loads(shapely.to_geojson(g))} for g in squares]
    path = tmp_path / "two_cities.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    with pytest.raises(MapLoadError, match="spread over 1,1") as error:
        load_map(path)
    assert error.value.code == "map_too_wide"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\x1f\x8b\x08\x00" + b"\x00" * 20, "cannot be decompressed"),
        (b"SQLite format 3\x00" + b"\x00" * 200, "not a GeoPackage"),
        (b"\x00\x00\x27\x0a" + b"\x00" * 200, "zipped together with its .shx"),
        (b"PK\x03\x04" + b"\x00" * 60, "zip archive that cannot be read"),
    ],
)
def test_other_containers_say_what_they_are(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "upload.bin"
    path.write_bytes(content)
    with pytest.raises(MapLoadError, match=message):
        load_map(path)
