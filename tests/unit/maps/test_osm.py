import bz2
import json
from pathlib import Path

import numpy as np
import pytest

from contracts.settings import shared_path
from geoloc.maps import MapLoadError, load_map, map_summary
from tests.scenes import l_shaped_building, square_building

ORIGIN = (60.17, 24.94)


def _osm_xml(nodes: list[tuple[int, float, float, dict]], ways: list[tuple[int, list[int], dict]], rels=()) -> str:
    parts = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="test">']
    for nid, lat, lon, tags in nodes:
        inner = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        parts.append(f'<node id="{nid}" version="1" lat="{lat}" lon="{lon}">{inner}</node>')
    for wid, refs, tags in ways:
        inner = "".join(f'<nd ref="{r}"/>' for r in refs) + "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        parts.append(f'<way id="{wid}" version="1">{inner}</way>')
    for rid, members, tags in rels:
        inner = "".join(f'<member type="way" ref="{ref}" role="{role}"/>' for ref, role in members)
        inner += "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        parts.append(f'<relation id="{rid}" version="1">{inner}</relation>')
    parts.append("</osm>")
    return "\n".join(parts)


def _square_nodes(first_id: int, lat: float, lon: float, d: float = 0.0002) -> list:
    return [
        (first_id, lat, lon, {}),
        (first_id + 1, lat, lon + d, {}),
        (first_id + 2, lat + d, lon + d, {}),
        (first_id + 3, lat + d, lon, {}),
    ]


@pytest.fixture(scope="module")
def helsinki():
    return load_map(shared_path("data", "osm", "helsinki.osm.pbf"))


def test_helsinki_pbf_loads_all_building_objects(helsinki) -> None:
    report = helsinki.report
    assert report.building_ways == 433 and report.building_relations == 67
    assert report.format == "pbf"
    skipped = report.skipped_unclosed + report.skipped_degenerate + report.skipped_incomplete_relations
    assert len(helsinki.buildings) >= 500 - skipped - 5  # relations may yield several rings
    assert len(helsinki.buildings) > 400
    assert len(helsinki.facades) > 5000
    named = [b for b in helsinki.buildings if b.name]
    assert any(b.name == "Ateneum" for b in named)
    assert {b.height_source for b in helsinki.buildings} == {"height", "levels", "default"}
    min_lat, min_lon, max_lat, max_lon = helsinki.bbox_wgs84
    assert 60.16 < min_lat < max_lat < 60.18 and 24.93 < min_lon < max_lon < 24.96


def test_building_ids_are_stable(helsinki) -> None:
    again = load_map(shared_path("data", "osm", "helsinki.osm.pbf"))
    assert [b.osm_id for b in again.buildings] == [b.osm_id for b in helsinki.buildings]
    assert [b.building_id for b in helsinki.buildings] == list(range(len(helsinki.buildings)))


def test_facade_normals_point_outward(helsinki) -> None:
    import shapely

    f = helsinki.facades
    midpoint = (f.start + f.end) / 2
    polygons = np.array([helsinki.buildings[b].polygon for b in f.building_id], dtype=object)
    step = 0.05 * f.normal
    # A small step along the normal leaves the facade's own footprint; a step against it enters it.
    outside = shapely.contains_xy(polygons, *(midpoint + step).T)
    inside = shapely.contains_xy(polygons, *(midpoint - step).T)
    assert np.mean(~outside) > 0.995 and np.mean(inside) > 0.995
    assert np.allclose(np.hypot(*f.normal.T), 1.0)


def test_square_facades_analytic() -> None:
    city = square_building()
    f = city.facades
    assert len(f) == 4 and np.allclose(f.length_m, 20.0, atol=1e-6)
    assert sorted((np.round(f.normal_bearing_deg).astype(int) % 360).tolist()) == [0, 90, 180, 270]
    assert city.buildings[0].height_m == 15.0 and city.buildings[0].name == "Square"


def test_l_shape_has_six_facades_with_one_concave_corner() -> None:
    f = l_shaped_building().facades
    assert len(f) == 6
    assert np.isclose(f.length_m.sum(), 50 + 10 + 40 + 20 + 10 + 30, atol=1e-6)


def test_osm_xml_bz2_and_geojson(tmp_path: Path) -> None:
    lat, lon = ORIGIN
    nodes = _square_nodes(1, lat, lon) + _square_nodes(11, lat + 0.001, lon) + _square_nodes(21, lat, lon + 0.001)
    nodes += [(31, lat + 0.0005, lon + 0.0005, {"natural": "tree"})]
    ways = [
        (100, [1, 2, 3, 4, 1], {"building": "yes", "name": "A", "height": "21 m"}),
        (101, [11, 12, 13, 14, 11], {"building": "house", "building:levels": "2"}),
        (102, [21, 22, 23], {"building": "yes"}),  # outer way of the relation, split in two
        (103, [23, 24, 21], {}),
        (104, [1, 11], {"highway": "residential"}),
    ]
    rels = [(200, [(102, "outer"), (103, "outer")], {"type": "multipolygon", "building": "yes"})]
    xml = _osm_xml(nodes, ways, rels)
    (tmp_path / "a.osm").write_text(xml)
    (tmp_path / "a.osm.bz2").write_bytes(bz2.compress(xml.encode()))
    for name in ("a.osm", "a.osm.bz2"):
        city = load_map(tmp_path / name)
        # way/102 is tagged building but open with a 22 m gap: skipped; the relation joins 102 + 103.
        assert [b.osm_id for b in city.buildings] == ["relation/200", "way/100", "way/101"]
        assert city.report.skipped_unclosed == 1
        heights = {b.osm_id: b.height_m for b in city.buildings}
        assert heights["way/100"] == 21.0 and heights["way/101"] == 6.0
        assert len(city.trees) == 1 and len(city.streets) == 1

    geojson = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "id": "b1",
                "properties": {"building": "yes", "name": "G"},
                "geometry": {
                    "type": "Polygon",
                    "coordinates": [[[lon, lat], [lon + 0.0002, lat], [lon, lat + 0.0002]]],
                },
            },
            {"type": "Feature", "properties": {"building": "no"}, "geometry": {"type": "Point", "coordinates": [0, 0]}},
        ],
    }
    (tmp_path / "b.json").write_text(json.dumps(geojson))
    city = load_map(tmp_path / "b.json")
    assert len(city.buildings) == 1 and city.buildings[0].name == "G"
    assert city.report.closed_unclosed_ways == 1  # the ring was not closed


def test_broken_geometry_is_counted_not_raised(tmp_path: Path) -> None:
    lat, lon = ORIGIN
    nodes = _square_nodes(1, lat, lon) + _square_nodes(11, lat + 0.001, lon)
    nodes += [(40, lat + 0.002, lon, {}), (41, lat + 0.002, lon + 0.0002, {})]
    ways = [
        (100, [1, 2, 3, 4, 1], {"building": "yes"}),
        (101, [11, 13, 12, 14, 11], {"building": "yes"}),  # bow-tie: self-intersecting
        (102, [40, 41, 40], {"building": "yes"}),  # degenerate
        (103, [1, 2, 3, 4, 999, 1], {"building": "yes"}),  # references a missing node
    ]
    (tmp_path / "broken.osm").write_text(_osm_xml(nodes, ways))
    city = load_map(tmp_path / "broken.osm")
    report = city.report
    assert report.repaired_invalid == 1 and report.skipped_degenerate == 1 and report.missing_node_refs == 1
    assert len(city.buildings) == 3
    summary = map_summary(city)
    assert summary["buildings"] == 3 and summary["report"]["repaired_invalid"] == 1


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\x89PNG\r\n\x1a\n" + b"\0" * 100, "not map data"),
        (b"<html><body>hi</body></html>", "not OpenStreetMap"),
        (b'<?xml version="1.0"?><osm version="0.6"><node id="1" lat="60" lon="24"/></osm>', "no buildings"),
        (b'<?xml version="1.0"?><osm version="0.6"><node id="1" lat="60" lo', "cannot read"),
        (b'{"type": "FeatureCollection", "features": [', "not valid GeoJSON"),
        (b'{"type": "FeatureCollection", "features": []}', "no buildings"),
        (bz2.compress(b"hello world"), "bz2"),
    ],
)
def test_not_map_data_raises_clear_error(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "map.osm"
    path.write_bytes(content)
    with pytest.raises(MapLoadError, match=message):
        load_map(path)


def test_relations_of_closed_rings_built_together_as_one_by_one() -> None:
    """Relations whose ways are all closed rings are built in one vectorised pass (issue 23's map upload).

    Holes cut, outers joined, a bow-tie repaired, a relation left without area skipped, each counted as before.
    """
    from geoloc.core.geo import LocalFrame
    from geoloc.maps.build import RawMap, RawRelation, _relation_footprint, _relation_footprints, build_city_map
    from geoloc.maps.model import LoadReport

    frame = LocalFrame(*ORIGIN)

    def ring(corners_m: list[tuple[float, float]], east_m: float, closed: bool = True) -> np.ndarray:
        """(lon, lat) degrees of (east, north) metre corners shifted by east_m; closed: the first repeated last."""
        east, north = np.array([*corners_m, *corners_m[:1]] if closed else corners_m, dtype=float).T
        lat, lon = frame.to_wgs84(east + east_m, north)
        return np.column_stack([lon, lat])

    square = [(0, 0), (20, 0), (20, 20), (0, 20)]
    hole = [(5, 5), (10, 5), (10, 10), (5, 10)]
    relations = {
        "holed": ([square], [hole]),
        "two holes": ([square], [hole, [(12, 12), (15, 12), (15, 15), (12, 15)]]),
        "two outers": ([square, [(40, 0), (50, 0), (50, 10), (40, 10)]], []),
        "overlapping outers": ([square, [(10, 10), (30, 10), (30, 30), (10, 30)]], []),
        "bow-tie": ([[(0, 0), (20, 20), (20, 0), (0, 20)]], []),
        "filled hole": ([hole], [square]),
        "split outer": ([[(0, 0), (20, 0), (20, 20)], [(20, 20), (0, 20), (0, 0)]], []),
    }
    raw = RawMap("osm", LoadReport(format="osm"))
    for index, (name, (outers, inners)) in enumerate(relations.items()):
        east_m, closed = 100.0 * index, name != "split outer"  # each relation on its own ground
        raw.relations.append(
            RawRelation(
                f"relation/{index}",
                {"building": "yes", "name": name},
                [ring(corners, east_m, closed) for corners in outers],
                [ring(corners, east_m) for corners in inners],
            )
        )
    city = build_city_map(raw, "relations", frame=frame)
    areas = {b.name: b.polygon.area for b in city.buildings}
    parts = {b.name: len(getattr(b.polygon, "geoms", [b.polygon])) for b in city.buildings}
    assert "filled hole" not in areas  # its hole covers it: nothing left
    assert areas["holed"] == pytest.approx(400 - 25, rel=1e-3)
    assert areas["two holes"] == pytest.approx(400 - 25 - 9, rel=1e-3)
    assert areas["two outers"] == pytest.approx(500, rel=1e-3) and parts["two outers"] == 2
    assert areas["overlapping outers"] == pytest.approx(400 + 400 - 100, rel=1e-3) and parts["overlapping outers"] == 1
    assert areas["bow-tie"] == pytest.approx(200, rel=1e-3) and parts["bow-tie"] == 2
    assert areas["split outer"] == pytest.approx(400, rel=1e-3)  # joined from its two ways, one by one
    assert city.report.repaired_invalid == 1 and city.report.skipped_degenerate == 1
    # Each footprint is the one-by-one path's, to the byte.
    together = _relation_footprints(raw.relations, frame, LoadReport(format="osm"))
    for relation, footprint in zip(raw.relations, together, strict=True):
        local = [
            [np.column_stack(frame.to_local(r[:, 1], r[:, 0])) for r in rings]
            for rings in (relation.outers, relation.inners)
        ]
        alone = _relation_footprint(*local, LoadReport(format="osm"))
        assert (footprint is None) == (alone is None) and (alone is None or footprint.wkb == alone.wkb), relation.tags
