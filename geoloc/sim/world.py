"""Simulated worlds: sample reference and query poses on a map, render them, write photos + ground truth.

Layout of a world folder (``geoloc sim world``)::

    manifest.json          map, options, sun, and per image: pose (local + WGS84), intrinsics, GPS
                           written to EXIF, file paths, visible buildings with pixel shares
    references/NAME.jpg    reference photos (EXIF GPS with noise, focal length, make/model, time)
    queries/NAME.jpg       query photos (EXIF GPS with more noise, or none)
    gt/NAME.npz            labels (H, W) uint8, building_id (H, W) int32, facade_id (H, W) int32,
                           column_theta_deg, column_distance_m (W,) float32,
                           column_building_id, column_facade_id (W,) int32
    contact_sheet.jpg      thumbnails with names, and a map of the poses

Sampling (deterministic for a seed): the world is a disk of ``radius_m`` around a centre near the
buildings' median. References stand along streets (OSM highways; without streets, in free space
8-25 m in front of facades), mostly facing across the street (perpendicular +- 15 deg) with at
least 60 % of the view on buildings within 60 m, at least ``min_ref_spacing_m`` apart. Queries are
of three kinds: ``between`` two nearby references, ``offset`` from one reference (moved and turned
20-70 deg), and ``unseen``: looking at a building that no reference shows with more than 2 % of
its pixels.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.maps import CityMap, load_map
from geoloc.maps.raycast import cast_panoramas, panorama_window
from geoloc.photos.exif import write_jpeg
from geoloc.sim.render import Pose, Render, render
from geoloc.sim.scene import Scene

FULL_FRAME_WIDTH_MM = 36.0
PHONE_CROP_FACTOR = 7.0  # 35 mm-equivalent / physical focal length of a typical phone main camera
QUERY_KINDS = ("between", "offset", "unseen")
MANIFEST_VERSION = 1


@dataclass
class WorldOptions:
    """Options of :func:`generate_world` (see ``geoloc sim world --help``)."""

    n_references: int = 60
    n_queries: int = 30
    seed: int = 1
    gps_noise_m: float = 5.0
    query_gps_noise_m: float = 20.0  # negative: queries carry no GPS
    width: int = 640
    height: int = 480
    hfov_deg: float = 60.0
    radius_m: float = 220.0  # 0: the whole map
    min_ref_spacing_m: float = 10.0
    pitch_std_deg: float = 1.0
    roll_std_deg: float = 0.3
    jpeg_quality: int = 90


def camera_for(width: int, height: int, hfov_deg: float) -> tuple[Intrinsics, int, float]:
    """Intrinsics whose focal length is an integer 35 mm equivalent (as EXIF stores it).

    Returns (intrinsics, focal_35mm, focal_mm); the field of view is the nearest one to ``hfov_deg``
    that an integer FocalLengthIn35mmFilm gives on the image's longer side.
    """
    long_side = max(width, height)
    f35_exact = FULL_FRAME_WIDTH_MM / 2.0 / math.tan(math.radians(hfov_deg) / 2.0) * long_side / width
    f35 = max(1, int(round(f35_exact)))
    focal_px = f35 / FULL_FRAME_WIDTH_MM * long_side
    intr = Intrinsics(width, height, focal_px, width / 2.0, height / 2.0, "exif_35mm")
    return intr, f35, round(f35 / PHONE_CROP_FACTOR, 2)


# ----------------------------------------------------------------------------------------------
# Pose sampling


@dataclass
class _Candidates:
    xy: np.ndarray  # (N, 2)
    yaw_deg: np.ndarray  # (N,)


def _world_centre(city_map: CityMap) -> np.ndarray:
    cent = np.array([b.polygon.centroid.coords[0] for b in city_map.buildings])
    centre: np.ndarray = np.median(cent, axis=0)
    return centre


def _street_points(
    city_map: CityMap, rng: np.random.Generator, n: int, centre: np.ndarray, radius_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random points on streets inside the disk (uniform by length): (n, 2) xy, (n, 2) unit directions."""
    segs_a, segs_b = [], []
    for line in city_map.streets:
        if len(line) >= 2:
            segs_a.append(line[:-1])
            segs_b.append(line[1:])
    if not segs_a:
        return np.zeros((0, 2)), np.zeros((0, 2))
    a, b = np.concatenate(segs_a), np.concatenate(segs_b)
    mid = (a + b) / 2
    if radius_m > 0:
        keep = np.hypot(*(mid - centre).T) <= radius_m
        a, b = a[keep], b[keep]
    length = np.hypot(*(b - a).T)
    ok = length > 0.5
    a, b, length = a[ok], b[ok], length[ok]
    if len(a) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    k = rng.choice(len(a), n, p=length / length.sum())
    t = rng.random(n)[:, None]
    return a[k] + t * (b[k] - a[k]), (b[k] - a[k]) / length[k, None]


def _facade_points(
    city_map: CityMap, rng: np.random.Generator, n: int, centre: np.ndarray, radius_m: float
) -> _Candidates:
    """Free-space fallback: points 8-25 m in front of random facades, looking at them."""
    fac = city_map.facades
    mid = (fac.start + fac.end) / 2
    ok = fac.length_m > 3.0
    if radius_m > 0:
        ok &= np.hypot(*(mid - centre).T) <= radius_m
    idx = np.flatnonzero(ok) if ok.any() else np.arange(len(fac))
    k = rng.choice(idx, n, p=fac.length_m[idx] / fac.length_m[idx].sum())
    along = (fac.end[k] - fac.start[k]) * rng.uniform(0.1, 0.9, (n, 1))
    xy = fac.start[k] + along + fac.normal[k] * rng.uniform(8.0, 25.0, (n, 1))
    yaw = (fac.normal_bearing_deg[k] + 180.0 + rng.normal(0, 20.0, n)) % 360.0
    return _Candidates(xy, yaw)


def _street_candidates(
    city_map: CityMap, rng: np.random.Generator, n: int, centre: np.ndarray, radius_m: float
) -> _Candidates:
    """Street positions (on the road or the pavement) looking across the street, either side."""
    xy, d = _street_points(city_map, rng, n, centre, radius_m)
    if len(xy) == 0:
        return _facade_points(city_map, rng, n, centre, radius_m)
    normal = np.column_stack([d[:, 1], -d[:, 0]])
    side = rng.choice([-1.0, 1.0], len(xy))[:, None]
    xy = xy + normal * side * rng.uniform(-2.0, 7.0, (len(xy), 1))  # mostly on the far side of the street
    look = -normal * side  # mostly across the street
    yaw = (np.degrees(np.arctan2(look[:, 0], look[:, 1])) + rng.normal(0, 15.0, len(xy))) % 360.0
    return _Candidates(xy, yaw)


@dataclass
class _View:
    """Cheap view statistics from the ray-cast panorama: building coverage, median distance, main building."""

    coverage: np.ndarray
    median_dist_m: np.ndarray
    main_building: np.ndarray


def _views(scene: Scene, xy: np.ndarray, yaw_deg: np.ndarray, hfov_deg: float, near_m: float = 60.0) -> _View:
    pano = cast_panoramas(scene.map, xy, bearing_step_deg=1.0, max_range_m=near_m * 2, index=scene.index)
    offsets = np.arange(-hfov_deg / 2 + 0.5, hfov_deg / 2, 1.0)
    win = panorama_window(pano, yaw_deg, offsets)  # (N, K)
    rows = np.arange(len(xy))[:, None]
    dist = pano.distance_m[rows, win]
    bid = pano.building_id[rows, win]
    near = dist <= near_m
    coverage = near.mean(axis=1)
    masked = np.where(near, dist, np.inf)
    med = np.where(
        near.any(axis=1), np.sort(masked, axis=1)[np.arange(len(xy)), np.maximum(near.sum(1) // 2, 0)], np.inf
    )
    main = np.full(len(xy), -1)
    for i in range(len(xy)):
        ids = bid[i][near[i]]
        if len(ids):
            main[i] = np.bincount(ids).argmax()
    return _View(coverage, med, main)


def _valid_positions(scene: Scene, xy: np.ndarray, margin_m: float = 1.5) -> np.ndarray:
    return scene._clear_of_buildings(xy, margin_m)


def _pitch_roll(rng: np.random.Generator, opts: WorldOptions) -> tuple[float, float]:
    pitch = float(np.clip(rng.normal(0, opts.pitch_std_deg), -3 * opts.pitch_std_deg, 3 * opts.pitch_std_deg))
    roll = float(np.clip(rng.normal(0, opts.roll_std_deg), -3 * opts.roll_std_deg, 3 * opts.roll_std_deg))
    return round(pitch, 3), round(roll, 3)


def sample_references(scene: Scene, opts: WorldOptions, rng: np.random.Generator, centre: np.ndarray) -> list[Pose]:
    """Reference poses along streets facing buildings (see module docstring)."""
    chosen: list[np.ndarray] = []
    yaws: list[float] = []
    spacing = opts.min_ref_spacing_m
    for _attempt in range(6):
        cand = _street_candidates(scene.map, rng, max(200, 40 * opts.n_references), centre, opts.radius_m)
        ok = _valid_positions(scene, cand.xy)
        view = _views(scene, cand.xy, cand.yaw_deg, opts.hfov_deg)
        ok &= (view.coverage >= 0.6) & (view.median_dist_m >= 8.0) & (view.median_dist_m <= 45.0)
        for i in np.flatnonzero(ok):
            if len(chosen) >= opts.n_references:
                break
            if chosen and np.min(np.hypot(*(np.array(chosen) - cand.xy[i]).T)) < spacing:
                continue
            chosen.append(cand.xy[i])
            yaws.append(float(cand.yaw_deg[i]))
        if len(chosen) >= opts.n_references:
            break
        spacing *= 0.7  # a small area: allow denser references
    poses = []
    for xy, yaw in zip(chosen, yaws, strict=True):
        pitch, roll = _pitch_roll(rng, opts)
        poses.append(Pose(round(float(xy[0]), 3), round(float(xy[1]), 3), round(yaw % 360.0, 3), pitch, roll))
    return poses


def sample_queries(
    scene: Scene,
    opts: WorldOptions,
    rng: np.random.Generator,
    centre: np.ndarray,
    refs: list[Pose],
    ref_seen: dict[int, float],
) -> list[tuple[str, Pose]]:
    """Query poses: ``between`` / ``offset`` references and ``unseen`` buildings (module docstring).

    ref_seen: building id -> largest pixel share it has in any reference.
    """
    n = opts.n_queries
    quotas = {"between": int(round(n * 0.4)), "offset": int(round(n * 0.3))}
    quotas["unseen"] = n - quotas["between"] - quotas["offset"]
    ref_xy = np.array([[p.x_m, p.y_m] for p in refs]).reshape(-1, 2)
    ref_yaw = np.array([p.yaw_deg for p in refs])
    out: list[tuple[str, np.ndarray, float]] = []
    m = max(100, 30 * n)
    for kind in QUERY_KINDS:
        want = quotas[kind]
        got = 0
        for _attempt in range(6):
            if want == 0:
                break
            cand, far = _query_candidates(kind, scene, opts, rng, centre, ref_xy, ref_yaw, m)
            ok = _valid_positions(scene, cand.xy) & ~far
            view = _views(scene, cand.xy, cand.yaw_deg, opts.hfov_deg)
            ok &= (view.coverage >= 0.45) & (view.median_dist_m >= 5.0) & (view.median_dist_m <= 60.0)
            if kind == "unseen":
                seen = np.array([ref_seen.get(int(b), 0.0) for b in view.main_building])
                ok &= (seen < 0.02) & (view.main_building >= 0)
            got += _accept_queries(out, kind, cand, ok, want - got)
            if got >= want:
                break
        if got < want:  # not enough of this kind (e.g. every building is seen): top up with the next kind
            nxt = QUERY_KINDS[(QUERY_KINDS.index(kind) + 1) % 3]
            if nxt != "between":
                quotas[nxt] += want - got
    result = []
    for kind, xy, yaw in out:
        pitch, roll = _pitch_roll(rng, opts)
        result.append((kind, Pose(round(float(xy[0]), 3), round(float(xy[1]), 3), round(yaw, 3), pitch, roll)))
    return result


def _query_candidates(
    kind: str,
    scene: Scene,
    opts: WorldOptions,
    rng: np.random.Generator,
    centre: np.ndarray,
    ref_xy: np.ndarray,
    ref_yaw: np.ndarray,
    m: int,
) -> tuple[_Candidates, np.ndarray]:
    """``m`` candidate query poses of one kind (local metres, yaw degrees) and (m,) bool: too far to use.

    ``between``: on the segment between a reference and one of its 3 nearest (too far beyond 80 m apart);
    ``offset``: 4-15 m from a reference, turned 20-70 deg; otherwise (``unseen``, or too few references)
    anywhere along the streets.
    """
    if kind == "between" and len(ref_xy) >= 2:
        i = rng.integers(len(ref_xy), size=m)
        d = np.hypot(*(ref_xy[:, None] - ref_xy[None]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        nn = np.argsort(d, axis=1)[:, :3]
        j = nn[i, rng.integers(0, min(3, len(ref_xy) - 1), m)]
        t = rng.uniform(0.3, 0.7, (m, 1))
        xy = ref_xy[i] * (1 - t) + ref_xy[j] * t + rng.normal(0, 2.0, (m, 2))
        diff = ((ref_yaw[j] - ref_yaw[i] + 180.0) % 360.0) - 180.0
        yaw = (ref_yaw[i] + diff * t[:, 0] + rng.normal(0, 25.0, m)) % 360.0
        return _Candidates(xy, yaw), d[i, j] > 80.0
    if kind == "offset" and len(ref_xy):
        i = rng.integers(len(ref_xy), size=m)
        ang = rng.uniform(0, 2 * np.pi, m)
        r = rng.uniform(4.0, 15.0, m)
        xy = ref_xy[i] + np.column_stack([np.cos(ang), np.sin(ang)]) * r[:, None]
        turn = rng.uniform(20.0, 70.0, m) * rng.choice([-1.0, 1.0], m)
        return _Candidates(xy, (ref_yaw[i] + turn) % 360.0), np.zeros(m, bool)
    cand = _street_candidates(scene.map, rng, m, centre, opts.radius_m)
    cand.yaw_deg = (cand.yaw_deg + rng.normal(0, 20.0, m)) % 360.0
    return cand, np.zeros(m, bool)


def _accept_queries(
    out: list[tuple[str, np.ndarray, float]], kind: str, cand: _Candidates, ok: np.ndarray, n_wanted: int
) -> int:
    """Append up to ``n_wanted`` of the ``ok`` candidates to ``out``; returns how many were appended.

    Candidates are taken in order, each at least 2 m from the queries already in ``out``.
    """
    taken = 0
    for q in np.flatnonzero(ok):
        if taken >= n_wanted:
            break
        if out and np.min(np.hypot(*(np.array([o[1] for o in out]) - cand.xy[q]).T)) < 2.0:
            continue
        out.append((kind, cand.xy[q], float(cand.yaw_deg[q])))
        taken += 1
    return taken


# ----------------------------------------------------------------------------------------------
# Writing


def _gps_with_noise(scene: Scene, pose: Pose, noise_m: float, rng: np.random.Generator) -> dict[str, Any] | None:
    if noise_m < 0:
        return None
    dx, dy = rng.normal(0, noise_m, 2) if noise_m > 0 else (0.0, 0.0)
    lat, lon = scene.map.frame.to_wgs84(pose.x_m + dx, pose.y_m + dy)
    return {
        "lat": float(lat),
        "lon": float(lon),
        "noise_east_m": float(dx),
        "noise_north_m": float(dy),
        "noise_std_m": float(noise_m),
    }


def _image_record(
    scene: Scene,
    name: str,
    role: str,
    kind: str,
    r: Render,
    f35: int,
    fmm: float,
    gps: dict[str, Any] | None,
    folder: str,
) -> dict[str, Any]:
    frame = scene.map.frame
    lat, lon = frame.to_wgs84(r.pose.x_m, r.pose.y_m)
    heading = float(frame.bearing_to_heading(r.pose.yaw_deg, r.pose.x_m, r.pose.y_m))
    intr = r.intrinsics
    buildings = []
    for b, share in r.building_shares().items():
        bld = scene.map.buildings[b]
        buildings.append({"building_id": b, "osm_id": bld.osm_id, "name": bld.name, "pixel_share": round(share, 5)})
    return {
        "name": name,
        "role": role,
        "kind": kind,
        "file": f"{folder}/{name}.jpg",
        "gt": f"gt/{name}.npz",
        "pose": {**r.pose.as_dict(), "lat": float(lat), "lon": float(lon), "heading_deg": round(heading, 4)},
        "intrinsics": {
            "width": intr.width,
            "height": intr.height,
            "focal_px": intr.focal_px,
            "cx": intr.cx,
            "cy": intr.cy,
            "hfov_deg": intr.hfov_deg,
            "focal_35mm": f35,
            "focal_mm": fmm,
        },
        "gps": gps,
        "building_fraction": float((r.building_id >= 0).mean()),
        "label_fractions": {
            k: float(v)
            for k, v in zip(
                ("other", "building", "tree", "road", "sky", "car"),
                np.bincount(r.labels.ravel(), minlength=6)[:6] / r.labels.size,
                strict=True,
            )
        },
        "buildings": buildings,
    }


def _save_gt(path: Path, r: Render) -> None:
    np.savez_compressed(
        path,
        labels=r.labels,
        building_id=r.building_id,
        facade_id=r.facade_id,
        column_theta_deg=r.column_theta_deg,
        column_distance_m=r.column_distance_m,
        column_building_id=r.column_building_id,
        column_facade_id=r.column_facade_id,
    )


def generate_world(
    map_path: str | Path,
    out_dir: str | Path,
    opts: WorldOptions | None = None,
    progress: Callable[[str], None] | None = None,
    city_map: CityMap | None = None,
) -> dict[str, Any]:
    """Sample, render and write a world (layout in the module docstring); returns the manifest."""
    opts = opts or WorldOptions()
    say = progress or (lambda _msg: None)
    t0 = time.perf_counter()
    out = Path(out_dir)
    for sub in ("references", "queries", "gt"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    city_map = city_map or load_map(map_path)
    scene = Scene(city_map, seed=opts.seed)
    say(
        f"map {city_map.source}: {len(city_map.buildings)} buildings, {len(scene.trees.xy)} trees, "
        f"{len(scene.cars.xy)} cars ({time.perf_counter() - t0:.1f} s)"
    )
    rng = np.random.default_rng([opts.seed, 100])
    centre = _world_centre(city_map)
    intr, f35, fmm = camera_for(opts.width, opts.height, opts.hfov_deg)
    refs = sample_references(scene, opts, rng, centre)
    say(f"sampled {len(refs)} reference poses")
    records: list[dict[str, Any]] = []
    ref_seen: dict[int, float] = {}
    gps_rng = np.random.default_rng([opts.seed, 200])
    for i, pose in enumerate(refs):
        name = f"ref_{i:03d}"
        r = render(scene, pose, intr, seed=opts.seed * 100_003 + i)
        for b, share in r.building_shares().items():
            ref_seen[b] = max(ref_seen.get(b, 0.0), share)
        gps = _gps_with_noise(scene, pose, opts.gps_noise_m, gps_rng)
        _write(out, "references", name, r, gps, f35, fmm, opts, i)
        records.append(_image_record(scene, name, "reference", "street", r, f35, fmm, gps, "references"))
        if (i + 1) % 10 == 0 or i + 1 == len(refs):
            say(f"references {i + 1}/{len(refs)} ({time.perf_counter() - t0:.1f} s)")
    queries = sample_queries(scene, opts, rng, centre, refs, ref_seen)
    say(f"sampled {len(queries)} query poses " + str({k: sum(q[0] == k for q in queries) for k in QUERY_KINDS}))
    for i, (kind, pose) in enumerate(queries):
        name = f"query_{i:03d}"
        r = render(scene, pose, intr, seed=opts.seed * 100_003 + 50_000 + i)
        gps = _gps_with_noise(scene, pose, opts.query_gps_noise_m, gps_rng)
        _write(out, "queries", name, r, gps, f35, fmm, opts, 10_000 + i)
        records.append(_image_record(scene, name, "query", kind, r, f35, fmm, gps, "queries"))
        if (i + 1) % 10 == 0 or i + 1 == len(queries):
            say(f"queries {i + 1}/{len(queries)} ({time.perf_counter() - t0:.1f} s)")
    lat0, lon0 = city_map.frame.to_wgs84(*centre)
    manifest = {
        "version": MANIFEST_VERSION,
        "generator": "geoloc.sim.world",
        "map": {
            "path": str(Path(map_path).resolve()) if map_path else None,
            "source": city_map.source,
            "origin_wgs84": {"lat": city_map.frame.origin_lat, "lon": city_map.frame.origin_lon},
        },
        "options": {k: getattr(opts, k) for k in opts.__dataclass_fields__},
        "region": {
            "centre_m": [float(centre[0]), float(centre[1])],
            "centre_wgs84": [float(lat0), float(lon0)],
            "radius_m": opts.radius_m,
        },
        "sun": {"azimuth_deg": scene.sun.azimuth_deg, "elevation_deg": scene.sun.elevation_deg},
        "camera_height_m": refs[0].height_m if refs else None,
        "conventions": {
            "local_frame": "x east, y north (m), azimuthal equidistant around map.origin_wgs84",
            "yaw_deg": "local bearing of the optical axis, clockwise from grid north",
            "heading_deg": "compass heading (true north) of the optical axis",
            "pixel_centres": "pixel (r, c) centre at (c + 0.5, r + 0.5); cx = width / 2",
            "column_theta_deg": "facade normal bearing - yaw, wrapped to [-90, 90); NaN: no facade",
            "column_distance_m": "horizontal distance along the column's ray to the nearest facade; inf: none",
        },
        "images": records,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    contact_sheet(out, manifest, scene)
    say(f"wrote {len(records)} images, manifest and contact sheet to {out} ({time.perf_counter() - t0:.1f} s)")
    return manifest


def _write(
    out: Path,
    folder: str,
    name: str,
    r: Render,
    gps: dict[str, Any] | None,
    f35: int,
    fmm: float,
    opts: WorldOptions,
    index: int,
) -> None:
    from datetime import datetime, timedelta

    taken = datetime(2024, 6, 1, 10, 0, 0) + timedelta(seconds=37 * index)
    write_jpeg(
        out / folder / f"{name}.jpg",
        r.rgb,
        lat=gps["lat"] if gps else None,
        lon=gps["lon"] if gps else None,
        focal_35mm=f35,
        focal_mm=fmm,
        quality=opts.jpeg_quality,
        altitude=12.0 if gps else None,
        taken=taken,
    )
    _save_gt(out / "gt" / f"{name}.npz", r)


# ----------------------------------------------------------------------------------------------
# Contact sheet


def contact_sheet(out: Path, manifest: dict[str, Any], scene: Scene, thumb_w: int = 192, cols: int = 10) -> Path:
    """Write ``contact_sheet.jpg``: thumbnails with names (blue: references, red: queries) and a pose map."""
    images = manifest["images"]
    th = int(round(thumb_w * 3 / 4))
    rows = max(1, math.ceil(len(images) / cols))
    label_h = 18
    grid = np.full((rows * (th + label_h), cols * thumb_w, 3), 30, np.uint8)
    for i, rec in enumerate(images):
        img = cv2.imread(str(out / rec["file"]))
        if img is None:
            continue
        thumb = cv2.resize(img, (thumb_w, th), interpolation=cv2.INTER_AREA)
        y, x = (i // cols) * (th + label_h), (i % cols) * thumb_w
        grid[y : y + th, x : x + thumb_w] = thumb
        colour = (230, 140, 40) if rec["role"] == "reference" else (40, 40, 230)
        grid[y + th : y + th + label_h, x : x + thumb_w] = colour
        text = rec["name"] + ("" if rec["role"] == "reference" else f" {rec['kind']}")
        cv2.putText(grid, text, (x + 4, y + th + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    side = grid.shape[0]
    plan = _pose_map(manifest, scene, side)
    sheet = np.hstack([grid, plan])
    path = out / "contact_sheet.jpg"
    cv2.imwrite(str(path), sheet, [cv2.IMWRITE_JPEG_QUALITY, 88])
    return path


def _pose_map(manifest: dict[str, Any], scene: Scene, side: int) -> np.ndarray:
    """(side, side, 3) BGR plan view: footprints, streets, and each pose as a dot with its view wedge."""
    img = np.full((side, side, 3), 245, np.uint8)
    xy = np.array([[r["pose"]["x_m"], r["pose"]["y_m"]] for r in manifest["images"]]).reshape(-1, 2)
    if len(xy) == 0:
        return img
    lo, hi = xy.min(axis=0) - 40.0, xy.max(axis=0) + 40.0
    span = float(max(hi - lo))
    scale = (side - 20) / span

    def to_px(p: np.ndarray) -> np.ndarray:
        q = (np.asarray(p) - lo) * scale + 10
        return np.column_stack([q[:, 0], side - q[:, 1]]).round().astype(np.int32)

    for line in scene.map.streets:
        if len(line) >= 2:
            cv2.polylines(img, [to_px(line)], False, (215, 215, 215), max(1, int(6 * scale)), cv2.LINE_AA)
    for b in scene.map.buildings:
        for poly in getattr(b.polygon, "geoms", [b.polygon]):
            ring = np.asarray(poly.exterior.coords)
            if np.all(ring.max(axis=0) >= lo) and np.all(ring.min(axis=0) <= hi):
                cv2.fillPoly(img, [to_px(ring)], (170, 170, 170), cv2.LINE_AA)
    for rec in manifest["images"]:
        p = np.array([[rec["pose"]["x_m"], rec["pose"]["y_m"]]])
        yaw = math.radians(rec["pose"]["yaw_deg"])
        half = math.radians(rec["intrinsics"]["hfov_deg"] / 2)
        colour = (200, 110, 20) if rec["role"] == "reference" else (30, 30, 220)
        c = to_px(p)[0]
        for a in (yaw - half, yaw + half):
            tip = to_px(p + 15.0 * np.array([[math.sin(a), math.cos(a)]]))[0]
            cv2.line(img, tuple(int(v) for v in c), tuple(int(v) for v in tip), colour, 1, cv2.LINE_AA)
        cv2.circle(img, tuple(int(v) for v in c), 4, colour, -1, cv2.LINE_AA)
        cv2.putText(
            img,
            rec["name"].split("_")[-1],
            (int(c[0]) + 5, int(c[1]) - 4),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.35,
            colour,
            1,
            cv2.LINE_AA,
        )
    cv2.putText(
        img,
        f"references (blue) and queries (red); 15 m view wedges; {span:.0f} m across",
        (10, 20),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.5,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    return img


# ----------------------------------------------------------------------------------------------
# Loading


@dataclass
class WorldImage:
    """One photo of a world (a manifest record with helpers)."""

    root: Path
    record: dict[str, Any]

    @property
    def name(self) -> str:
        """The image's name in the manifest."""
        return str(self.record["name"])

    @property
    def role(self) -> str:
        """``"reference"`` or ``"query"``."""
        return str(self.record["role"])

    @property
    def path(self) -> Path:
        """The JPEG file."""
        return self.root / str(self.record["file"])

    @property
    def pose(self) -> Pose:
        """The true camera pose (local frame, metres and degrees)."""
        p = self.record["pose"]
        return Pose(p["x_m"], p["y_m"], p["yaw_deg"], p["pitch_deg"], p["roll_deg"], p["height_m"])

    @property
    def intrinsics(self) -> Intrinsics:
        """The true camera intrinsics (pixels)."""
        i = self.record["intrinsics"]
        return Intrinsics(i["width"], i["height"], i["focal_px"], i["cx"], i["cy"], "exif_35mm")

    def rgb(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB of the JPEG."""
        img = cv2.imread(str(self.path), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(self.path)
        return img[..., ::-1].copy()


@dataclass
class World:
    """A world folder: its manifest, images (references first) and lazily loaded ground-truth arrays."""

    root: Path
    manifest: dict[str, Any]
    images: list[WorldImage]
    _gt: dict[str, dict[str, np.ndarray]] = field(default_factory=dict, repr=False)

    @property
    def references(self) -> list[WorldImage]:
        """The reference images (geo-tagged)."""
        return [im for im in self.images if im.role == "reference"]

    @property
    def queries(self) -> list[WorldImage]:
        """The query images."""
        return [im for im in self.images if im.role == "query"]

    def image(self, name: str) -> WorldImage:
        """The image called ``name``; KeyError if there is none."""
        for im in self.images:
            if im.name == name:
                return im
        raise KeyError(name)

    def gt(self, name: str) -> dict[str, np.ndarray]:
        """Ground-truth arrays of an image (see module docstring), loaded on first use."""
        if name not in self._gt:
            with np.load(self.root / self.image(name).record["gt"]) as data:
                self._gt[name] = {k: data[k] for k in data.files}
        return self._gt[name]

    def load_map(self) -> CityMap:
        """The map the world was rendered from (path recorded in the manifest)."""
        return load_map(self.manifest["map"]["path"])


def load_world(root: str | Path) -> World:
    """Open a world folder written by :func:`generate_world`."""
    root = Path(root)
    manifest = json.loads((root / "manifest.json").read_text())
    if manifest.get("version") != MANIFEST_VERSION:
        raise ValueError(f"{root}: unsupported world manifest version {manifest.get('version')}")
    return World(root, manifest, [WorldImage(root, rec) for rec in manifest["images"]])
