"""Walk worlds (``--capture walk``): street walks, a phone's GPS, compass and capture times, on real OSM maps."""

from __future__ import annotations

import json
from datetime import datetime
from pathlib import Path

import numpy as np
import piexif
import pytest
import shapely

from contracts.settings import shared_path
from geoloc.maps import CityMap, load_map
from geoloc.photos.exif import read_exif
from geoloc.sim import Scene
from geoloc.sim.sampling import world_centre
from geoloc.sim.walks import (
    COMPASS_STD_DEG,
    GPS_STD_M,
    JUMP_M,
    PAUSE_S,
    SPEED_M_S,
    NoStreetsError,
    Shot,
    Walk,
    sample_walks,
)
from geoloc.sim.world import WorldOptions, generate_world, load_world

HELSINKI = shared_path("data", "osm", "helsinki.osm.pbf")
PATCH = shared_path("data", "osm", "germany_patch.osm")  # 31 buildings, 545 m of streets: a small real map


@pytest.fixture(scope="module")
def helsinki_walks() -> tuple[CityMap, Scene, list[Shot], list[Walk]]:
    """60 references on walks in Helsinki (poses and noise only, nothing rendered)."""
    city = load_map(HELSINKI)
    scene = Scene(city, seed=1)
    opts = WorldOptions(n_references=60, seed=1, capture="walk")
    shots, walks = sample_walks(scene, opts, np.random.default_rng([1, 300]), world_centre(city))
    return city, scene, shots, walks


def _by_walk(shots: list[Shot]) -> dict[int, list[Shot]]:
    out: dict[int, list[Shot]] = {}
    for s in shots:
        out.setdefault(s.walk_id, []).append(s)
    return out


def test_walks_take_every_reference_in_order(helsinki_walks: tuple[CityMap, Scene, list[Shot], list[Walk]]) -> None:
    _, _, shots, walks = helsinki_walks
    assert len(shots) == 60 and len(walks) == 4
    for walk_id, walk_shots in _by_walk(shots).items():
        assert [s.index for s in walk_shots] == list(range(len(walk_shots)))
        assert walks[walk_id].walk_id == walk_id and len(walk_shots) >= 10


def test_photos_are_4_to_12_m_apart_in_street_space(
    helsinki_walks: tuple[CityMap, Scene, list[Shot], list[Walk]],
) -> None:
    city, scene, shots, _ = helsinki_walks
    for walk_shots in _by_walk(shots).values():
        xy = np.array([[s.pose.x_m, s.pose.y_m] for s in walk_shots])
        step = np.hypot(*np.diff(xy, axis=0).T)
        assert step.min() >= 4.0 - 1e-3 and step.max() <= 12.0 + 1e-3
    xy = np.array([[s.pose.x_m, s.pose.y_m] for s in shots])
    assert scene._clear_of_buildings(xy, 1.0).all()  # outside every building, with a margin
    streets = shapely.MultiLineString([line for line in city.streets if len(line) >= 2])
    assert shapely.distance(shapely.points(xy), streets).max() <= 8.0  # beside a street, not in a yard
    assert all(1.45 <= s.pose.height_m <= 1.65 for s in shots)  # hand height
    modes = {s.heading_mode for s in shots}
    assert modes >= {"forward", "across"}


def test_gps_error_is_correlated_along_a_walk_with_a_phones_std(
    helsinki_walks: tuple[CityMap, Scene, list[Shot], list[Walk]],
) -> None:
    _, _, shots, walks = helsinki_walks
    pairs, normalised = [], []
    for walk_id, walk_shots in _by_walk(shots).items():
        std = walks[walk_id].gps_std_m
        assert GPS_STD_M[0] <= std <= GPS_STD_M[1]
        off = np.array([s.gps_offset_m for s in walk_shots])
        normalised.append(off / std)
        pairs.append(np.column_stack([off[:-1].ravel(), off[1:].ravel()]))
    both = np.concatenate(pairs)
    lag1 = np.corrcoef(both[:, 0], both[:, 1])[0, 1]
    assert lag1 > 0.5  # white noise would be near 0
    assert 0.5 <= float(np.concatenate(normalised).std()) <= 1.5
    jumps = np.hypot(*np.array([s.gps_jump_m for s in shots]).T)
    assert np.all((jumps == 0) | ((jumps >= JUMP_M[0]) & (jumps <= JUMP_M[1])))
    assert (jumps > 0).mean() < 0.3


def test_compass_on_most_photos_with_its_stated_accuracy(
    helsinki_walks: tuple[CityMap, Scene, list[Shot], list[Walk]],
) -> None:
    _, _, shots, walks = helsinki_walks
    with_compass = [s for s in shots if s.compass_error_deg is not None]
    assert 0.7 <= len(with_compass) / len(shots) <= 0.97
    for walk in walks:
        assert COMPASS_STD_DEG[0] <= walk.compass_std_deg <= COMPASS_STD_DEG[1]
        assert 0.75 * walk.compass_std_deg <= walk.compass_accuracy_deg <= 1.3 * walk.compass_std_deg
    plain = [s for s in with_compass if not s.compass_outlier]
    norm = np.array([s.compass_error_deg for s in plain]) / np.array([walks[s.walk_id].compass_std_deg for s in plain])
    assert 0.4 <= float(np.sqrt(np.mean(norm**2))) <= 1.6
    assert all(abs(s.compass_error_deg or 0.0) >= 45.0 for s in with_compass if s.compass_outlier)


def test_capture_times_increase_at_a_walking_pace(
    helsinki_walks: tuple[CityMap, Scene, list[Shot], list[Walk]],
) -> None:
    _, _, shots, walks = helsinki_walks
    for walk_id, walk_shots in _by_walk(shots).items():
        t = np.array([s.capture_time.timestamp() for s in walk_shots])
        xy = np.array([[s.pose.x_m, s.pose.y_m] for s in walk_shots])
        dt, dist = np.diff(t), np.hypot(*np.diff(xy, axis=0).T)
        assert np.all(dt > 0)
        speed = walks[walk_id].speed_m_s
        assert SPEED_M_S[0] <= speed <= SPEED_M_S[1]
        pause = dt - dist / speed  # the walked path is at least the straight line: the pause is at most PAUSE_S
        assert pause.min() >= PAUSE_S[0] - 0.01
    starts = [walk_shots[0].capture_time for walk_shots in _by_walk(shots).values()]
    assert starts == sorted(starts)


def test_a_small_walk_world_is_deterministic_and_round_trips(tmp_path: Path) -> None:
    city = load_map(PATCH)
    opts = WorldOptions(n_references=6, n_queries=4, seed=3, width=160, height=120, radius_m=0.0, capture="walk")
    m1 = generate_world(PATCH, tmp_path / "w1", opts, city_map=city)
    m2 = generate_world(PATCH, tmp_path / "w2", opts, city_map=city)
    assert json.dumps(m1["images"]) == json.dumps(m2["images"]) and m1["walks"] == m2["walks"]
    assert m1["options"]["capture"] == "walk"
    for name in ("references/ref_000.jpg", "queries/query_000.jpg"):
        assert (tmp_path / "w1" / name).read_bytes() == (tmp_path / "w2" / name).read_bytes()
    world = load_world(tmp_path / "w1")
    assert world.manifest == m1 and len(world.references) == 6 and len(world.queries) == 4
    uuids = {w["walk_id"]: w["sequence_uuid"] for w in m1["walks"]}
    times = []
    for im in world.references:
        rec = im.record
        assert rec["kind"] == "walk" and rec["walk"]["sequence_uuid"] == uuids[rec["walk"]["walk_id"]]
        raw = piexif.load(str(im.path))
        desc = json.loads(raw["0th"][piexif.ImageIFD.ImageDescription])
        assert desc["MAPSequenceUUID"] == rec["walk"]["sequence_uuid"]
        taken = datetime.fromisoformat(rec["capture_time"])
        times.append(taken)
        assert raw["Exif"][piexif.ExifIFD.DateTimeOriginal] == taken.strftime("%Y:%m:%d %H:%M:%S").encode()
        assert raw["Exif"][piexif.ExifIFD.SubSecTimeOriginal] == f"{taken.microsecond // 1000:03d}".encode()
        exif = read_exif(im.path)
        gps = rec["gps"]
        assert exif.lat == pytest.approx(gps["lat"], abs=1e-8) and exif.lon == pytest.approx(gps["lon"], abs=1e-8)
        assert gps["noise_east_m"] == pytest.approx(gps["offset_east_m"] + gps["jump_east_m"])
        lat, lon = city.frame.to_wgs84(im.pose.x_m + gps["noise_east_m"], im.pose.y_m + gps["noise_north_m"])
        assert (lat, lon) == pytest.approx((gps["lat"], gps["lon"]), abs=1e-9)
        compass = rec["compass"]
        if compass is None:
            assert exif.heading_deg is None and "MAPCompassHeading" not in desc
            continue
        assert exif.heading_ref == "T" and exif.heading_deg == pytest.approx(compass["heading_deg"], abs=0.01)
        assert desc["MAPCompassHeading"]["AccuracyDegrees"] == compass["stated_accuracy_deg"]
        true_heading = rec["pose"]["heading_deg"]
        err = (compass["heading_deg"] - true_heading + 180.0) % 360.0 - 180.0
        assert err == pytest.approx((compass["error_deg"] + 180.0) % 360.0 - 180.0, abs=0.01)
    assert times == sorted(times)
    for im in world.queries:
        assert im.record["kind"] in ("between", "offset", "unseen") and "compass" in im.record


def test_walks_need_streets(tmp_path: Path) -> None:
    ring = [[24.9400, 60.1700], [24.9402, 60.1700], [24.9402, 60.1701], [24.9400, 60.1701], [24.9400, 60.1700]]
    geometry = {"type": "Polygon", "coordinates": [ring]}
    feature = {"type": "Feature", "properties": {"building": "yes"}, "geometry": geometry}
    path = tmp_path / "one.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    city = load_map(path)
    with pytest.raises(NoStreetsError, match="streets"):
        sample_walks(Scene(city), WorldOptions(n_references=5, capture="walk"), np.random.default_rng(0), np.zeros(2))
