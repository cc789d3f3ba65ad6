"""Spatial indexes of a loaded map and its stored copy.

The answers of the indexed lookups are the ones a scan of the whole map gives, work near a place does
not see the rest of a larger map, and a stored map reads back equal.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely

from contracts.settings import shared_path
from geoloc.core.array_file import is_mapped, map_arrays, write_arrays
from geoloc.localize.posterior import make_grid
from geoloc.maps import (
    CityMap,
    FacadeIndex,
    LoadReport,
    load_map,
    load_map_cached,
    map_cache_path,
    read_city_map,
    save_city_map,
)
from geoloc.maps.build import RawMap, build_city_map
from geoloc.maps.raycast import cast_all_hits, cast_panoramas
from tests.map_files import helsinki_wgs84


@pytest.fixture(scope="module")
def helsinki() -> CityMap:
    return load_map(shared_path("data", "osm", "helsinki.osm.pbf"))


def test_inside_buildings_matches_the_union_of_footprints(helsinki: CityMap) -> None:
    grid = make_grid(helsinki, helsinki.bounds_m, 7.3, exclude_inside=False)
    xy = grid.positions
    expected = shapely.contains_xy(helsinki.building_union, xy[:, 0], xy[:, 1])
    assert expected.sum() > 1000
    assert np.array_equal(helsinki.inside_buildings(xy), expected)
    assert not helsinki.inside_buildings(np.zeros((0, 2))).size


def test_buildings_near_a_box_are_the_ones_that_touch_it(helsinki: CityMap) -> None:
    box = (-100.0, -100.0, 100.0, 100.0)
    expected = np.flatnonzero(shapely.intersects(helsinki.footprints, shapely.box(*box)))
    assert len(expected) > 5
    assert np.array_equal(helsinki.buildings_near(box), expected)


def test_facade_index_finds_every_facade_in_range(helsinki: CityMap) -> None:
    facades = helsinki.facades
    index = helsinki.facade_index
    assert helsinki.facade_index is index, "built once, kept with the map"
    rng = np.random.default_rng(0)
    lo, hi = np.array(helsinki.bounds_m[:2]), np.array(helsinki.bounds_m[2:])
    for _ in range(20):
        center = rng.uniform(lo - 100, hi + 100, size=(int(rng.integers(1, 30)), 2))
        radius = float(rng.uniform(10, 300))
        found = set(index.facades_near(center, radius).tolist())
        # Brute force: facades whose bounding box comes within the radius of the centres' bounding box.
        box_lo, box_hi = center.min(axis=0) - radius, center.max(axis=0) + radius
        f_lo, f_hi = np.minimum(facades.start, facades.end), np.maximum(facades.start, facades.end)
        near = np.flatnonzero(np.all(f_hi >= box_lo, axis=1) & np.all(f_lo <= box_hi, axis=1))
        assert set(near.tolist()) <= found
        assert len(found) <= max(3 * len(near), len(near) + 200), "cells are local, not the whole map"


def test_facade_index_memory_grows_with_facades_not_extent() -> None:
    class TwoTowns:  # two 10 m walls 300 km apart
        start = np.array([[0.0, 0.0], [300_000.0, 0.0]])
        end = np.array([[10.0, 0.0], [300_010.0, 0.0]])

    index = FacadeIndex(TwoTowns())
    assert len(index.cell_keys) <= 4
    assert index.facades_near(np.array([[300_005.0, 5.0]]), 20.0).tolist() == [1]
    assert index.facades_near(np.array([[150_000.0, 0.0]]), 20.0).tolist() == []


def _tiled(helsinki: CityMap, tiles_per_side: int, gap_m: float = 30.0) -> CityMap:
    """Copies of the Helsinki footprints side by side, in the same local frame.

    The original is in the middle at its own place.
    """
    min_x, min_y, max_x, max_y = helsinki.bounds_m
    step = np.array([max_x - min_x + gap_m, max_y - min_y + gap_m])
    half = tiles_per_side // 2
    geoms, ids = [], []
    for i in range(-half, tiles_per_side - half):
        for j in range(-half, tiles_per_side - half):
            geoms.append(shapely.transform(helsinki.footprints, lambda xy, d=step * (i, j): xy + d))
            ids += [f"tile{i},{j}/{b.osm_id}" for b in helsinki.buildings]

    def to_lonlat(xy: np.ndarray) -> np.ndarray:
        lat, lon = helsinki.frame.to_wgs84(xy[:, 0], xy[:, 1])
        return np.column_stack([lon, lat])

    raw = RawMap("footprints", LoadReport("footprints"))
    raw.feature_geoms = shapely.transform(np.concatenate(geoms), to_lonlat)
    raw.feature_ids = ids
    raw.feature_tags = [b.tags for b in helsinki.buildings] * tiles_per_side**2
    return build_city_map(raw, "tiled", frame=helsinki.frame)


def test_ray_casting_in_the_middle_of_a_larger_map_sees_only_its_neighbourhood(helsinki: CityMap) -> None:
    tiled = _tiled(helsinki, 3)
    assert len(tiled.buildings) == 9 * len(helsinki.buildings)
    min_x, min_y, max_x, max_y = helsinki.bounds_m
    inner = (min_x + 260, min_y + 260, max_x - 260, max_y - 260)  # farther than the ray range from other tiles
    grid = make_grid(helsinki, inner, 40.0)
    assert len(grid.positions) > 50
    alone = cast_panoramas(helsinki, grid.positions)
    among = cast_panoramas(tiled, grid.positions)
    original = np.array([b.osm_id.startswith("tile0,0/") for b in tiled.buildings])
    hit = among.building_id >= 0
    assert np.array_equal(hit, alone.building_id >= 0)
    assert original[among.building_id[hit]].all(), "nothing of the other tiles is in range"
    assert np.array_equal(among.building_id[hit] % len(helsinki.buildings), alone.building_id[hit])
    assert np.allclose(among.distance_m[hit], alone.distance_m[hit], atol=0.02)
    # The renderer's caster too.
    position, bearings = grid.positions[0], np.arange(0.0, 60.0, 0.5)
    ray_a, _, dist_a, _ = cast_all_hits(helsinki, position, bearings)
    ray_b, _, dist_b, _ = cast_all_hits(tiled, position, bearings)
    assert np.array_equal(ray_a, ray_b) and np.allclose(dist_a, dist_b, atol=0.02)
    assert np.array_equal(tiled.inside_buildings(grid.positions), helsinki.inside_buildings(grid.positions))


def test_stored_map_reads_back_equal(helsinki: CityMap, tmp_path: Path) -> None:
    path = tmp_path / "helsinki.citymap.npz"
    save_city_map(helsinki, path)
    again = read_city_map(path)
    assert [(b.building_id, b.osm_id, b.name, b.height_m, b.height_source, b.tags) for b in again.buildings] == [
        (b.building_id, b.osm_id, b.name, b.height_m, b.height_source, b.tags) for b in helsinki.buildings
    ]
    assert all(shapely.equals_exact(again.footprints, helsinki.footprints, tolerance=0.0))
    for name in ("start", "end", "normal", "normal_bearing_deg", "length_m", "building_id"):
        assert np.array_equal(getattr(again.facades, name), getattr(helsinki.facades, name)), name
    assert np.array_equal(again.trees, helsinki.trees)
    assert len(again.streets) == len(helsinki.streets) > 100
    assert all(np.allclose(a, b) for a, b in zip(again.streets, helsinki.streets, strict=True))
    assert again.bbox_wgs84 == helsinki.bbox_wgs84 and again.report == helsinki.report
    assert again.frame.origin_lat == helsinki.frame.origin_lat and again.source == helsinki.source


def test_load_map_cached_parses_once(tmp_path: Path) -> None:
    source = tmp_path / "helsinki.geojson"
    city = load_map(shared_path("data", "osm", "helsinki.osm.pbf"))
    features = [
        {"type": "Feature", "properties": {"name": b.name}, "geometry": json.loads(shapely.to_geojson(g))}
        for b, g in zip(city.buildings, helsinki_wgs84(city), strict=True)
    ]
    source.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    cache = tmp_path / "cache"
    first = load_map_cached(source, cache, sha256="ab" * 32)
    stored = map_cache_path(cache, "ab" * 32)
    assert stored.is_file() and len(first.buildings) == len(city.buildings)
    source.unlink()  # the second load must come from the stored copy
    second = load_map_cached(source, cache, sha256="ab" * 32)
    assert [b.name for b in second.buildings] == [b.name for b in first.buildings]
    stored.write_bytes(b"not a stored map")  # a damaged copy is replaced from the source
    source.write_text(json.dumps({"type": "FeatureCollection", "features": features[:10]}))
    assert len(load_map_cached(source, cache, sha256="ab" * 32).buildings) == 10
    assert len(read_city_map(stored).buildings) == 10


def test_stored_map_is_mapped_read_only_with_its_indexes_and_casts_the_same(helsinki: CityMap, tmp_path: Path) -> None:
    path = map_cache_path(tmp_path, "cd" * 32)
    assert path.name.endswith("-v4.citymap.npz")  # format 4: an older version's file is never read
    save_city_map(helsinki, path)
    again = read_city_map(path)
    assert not again.facades.start.flags.writeable and is_mapped(again.facades.start)
    assert "facade_index" in vars(again) and "bounds_m" in vars(again)  # stored, not rebuilt
    fresh = FacadeIndex(helsinki.facades)
    for name in ("origin", "cell_keys", "cell_start", "cell_facades"):
        assert np.array_equal(getattr(again.facade_index, name), getattr(fresh, name)), name
    assert (again.facade_index.rows, again.facade_index.cell_m) == (fresh.rows, fresh.cell_m)
    assert again.bounds_m == helsinki.bounds_m
    positions = make_grid(helsinki, helsinki.bounds_m, 40.0).positions[:300]
    a, b = cast_panoramas(again, positions), cast_panoramas(helsinki, positions)
    assert a.building_id.tobytes() == b.building_id.tobytes() and a.distance_m.tobytes() == b.distance_m.tobytes()


def test_a_stored_map_of_another_version_is_refused(helsinki: CityMap, tmp_path: Path) -> None:
    path = tmp_path / "m.citymap.npz"
    save_city_map(helsinki, path)
    arrays = dict(map_arrays(path))
    meta = json.loads(arrays["meta"].tobytes())
    meta["version"] = 3
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    write_arrays(path, arrays)
    with pytest.raises(ValueError, match="version 3"):
        read_city_map(path)
