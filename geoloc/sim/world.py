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

A walk world (``WorldOptions.capture == "walk"``, :mod:`geoloc.sim.walks`) has its references on walks
and adds to the manifest ``options.capture``, ``walks`` (each walk's phone: GPS and compass noise
parameters, pace, sequence UUID) and, per image, ``walk`` (walk id, index in the walk, heading mode),
``compass`` (the heading written, its error, outlier flag, true std and stated accuracy; null: none) and
``capture_time``, with the GPS record split into its correlated offset and jump; its photos carry
sub-second capture times, GPSImgDirection and a Mapillary-style ImageDescription (:mod:`geoloc.sim.phone`).
A world with query tracks (``WorldOptions.query_tracks``, :mod:`geoloc.sim.tracks`) adds query photos
``queries/track_TT_II.jpg`` of kind ``track``, each with its ``track`` (number) and ``index`` (place in the
track), its walk-style GPS record, ``compass``, ``capture_time`` and ``heading_mode``, and records
``options.query_tracks`` and ``options.track_length``.
A world drawn around a chosen centre (``WorldOptions.centre_wgs84``, ``geoloc sim world --centre LAT,LON``)
records it in ``options.centre_wgs84``; its ``region`` says the centre either way.
A scattered world has none of these keys, so it is byte-identical to one written before they existed; the
manifest version is unchanged (the loader needs nothing new).

The poses are sampled by :mod:`geoloc.sim.sampling` (deterministic for a seed), rendered by
:func:`geoloc.sim.render.render` and written here; :func:`load_world` reads a world folder back.
:class:`WorldOptions` and :func:`camera_for` live in :mod:`geoloc.sim.options` and are named here too,
where the simulator's users import them.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from geoloc.core.camera import Intrinsics
from geoloc.maps import CityMap, load_map
from geoloc.photos.exif import ExifFields, write_jpeg
from geoloc.sim.contact_sheet import contact_sheet
from geoloc.sim.options import WorldOptions, camera_for
from geoloc.sim.phone import query_photo, walk_photo
from geoloc.sim.pose import Pose
from geoloc.sim.render import Render, render
from geoloc.sim.sampling import QUERY_KINDS, sample_queries, sample_references, world_centre
from geoloc.sim.scene import Scene
from geoloc.sim.tracks import sample_tracks
from geoloc.sim.walks import Shot, Walk, sample_walks

__all__ = ["MANIFEST_VERSION", "World", "WorldImage", "WorldOptions", "camera_for", "generate_world", "load_world"]

MANIFEST_VERSION = 1


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


def _reference_poses(
    scene: Scene, opts: WorldOptions, rng: np.random.Generator, centre: np.ndarray
) -> tuple[list[Pose], list[Shot], list[Walk]]:
    """The references' poses, and for a walk world its shots and walks (empty for a scattered one).

    Walks draw from their own generator, so that a scattered world's draws from ``rng`` stay as they were.
    """
    if opts.capture == "walk":
        shots, walks = sample_walks(scene, opts, np.random.default_rng([opts.seed, 300]), centre)
        return [shot.pose for shot in shots], shots, walks
    return sample_references(scene, opts, rng, centre), [], []


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
    centre = _centre(city_map, opts)
    intr, f35, fmm = camera_for(opts.width, opts.height, opts.hfov_deg)
    walking = opts.capture == "walk"
    refs, shots, walks = _reference_poses(scene, opts, rng, centre)
    say(f"sampled {len(refs)} reference poses" + (f" on {len(walks)} walks" if walking else ""))
    records: list[dict[str, Any]] = []
    ref_seen: dict[int, float] = {}
    gps_rng = np.random.default_rng([opts.seed, 200])
    gps: dict[str, Any] | None
    extra: dict[str, Any] | None  # EXIF fields of a walk world's photos (phone.py), None in a scattered one
    for i, pose in enumerate(refs):
        name = f"ref_{i:03d}"
        r = render(scene, pose, intr, seed=opts.seed * 100_003 + i)
        for b, share in r.building_shares().items():
            ref_seen[b] = max(ref_seen.get(b, 0.0), share)
        if walking:
            gps, extra, phone = walk_photo(scene, shots[i], walks[shots[i].walk_id])
        else:
            gps, extra, phone = _gps_with_noise(scene, pose, opts.gps_noise_m, gps_rng), None, {}
        _write(out, "references", name, r, gps, f35, fmm, opts, i, extra)
        kind = "walk" if walking else "street"
        records.append({**_image_record(scene, name, "reference", kind, r, f35, fmm, gps, "references"), **phone})
        if (i + 1) % 10 == 0 or i + 1 == len(refs):
            say(f"references {i + 1}/{len(refs)} ({time.perf_counter() - t0:.1f} s)")
    queries = sample_queries(scene, opts, rng, centre, refs, ref_seen)
    compass_rng = np.random.default_rng([opts.seed, 400])
    say(f"sampled {len(queries)} query poses " + str({k: sum(q[0] == k for q in queries) for k in QUERY_KINDS}))
    for i, (kind, pose) in enumerate(queries):
        name = f"query_{i:03d}"
        r = render(scene, pose, intr, seed=opts.seed * 100_003 + 50_000 + i)
        gps = _gps_with_noise(scene, pose, opts.query_gps_noise_m, gps_rng)
        extra, phone = query_photo(scene, pose, compass_rng, _taken(10_000 + i)) if walking else (None, {})
        _write(out, "queries", name, r, gps, f35, fmm, opts, 10_000 + i, extra)
        records.append({**_image_record(scene, name, "query", kind, r, f35, fmm, gps, "queries"), **phone})
        if (i + 1) % 10 == 0 or i + 1 == len(queries):
            say(f"queries {i + 1}/{len(queries)} ({time.perf_counter() - t0:.1f} s)")
    records.extend(_render_tracks(scene, opts, out, intr, f35, fmm, say, t0))
    lat0, lon0 = city_map.frame.to_wgs84(*centre)
    manifest = {
        "version": MANIFEST_VERSION,
        "generator": "geoloc.sim.world",
        "map": {
            "path": str(Path(map_path).resolve()) if map_path else None,
            "source": city_map.source,
            "origin_wgs84": {"lat": city_map.frame.origin_lat, "lon": city_map.frame.origin_lon},
        },
        "options": {k: getattr(opts, k) for k in opts.__dataclass_fields__ if _recorded(opts, k)},
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
    if walking:
        manifest["walks"] = [w.as_dict() | {"n_photos": sum(s.walk_id == w.walk_id for s in shots)} for w in walks]
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    contact_sheet(out, manifest, scene)
    say(f"wrote {len(records)} images, manifest and contact sheet to {out} ({time.perf_counter() - t0:.1f} s)")
    return manifest


def _centre(city_map: CityMap, opts: WorldOptions) -> np.ndarray:
    """(2,) local xy (m) of the world disk's centre: ``opts.centre_wgs84`` when set, else the buildings' median."""
    if opts.centre_wgs84 is None:
        return world_centre(city_map)
    lat, lon = opts.centre_wgs84
    return np.array(city_map.frame.to_local(lat, lon), dtype=float)


def _recorded(opts: WorldOptions, key: str) -> bool:
    """Whether an option goes into the manifest: the walk, track and centre ones only when used (module docstring)."""
    if key == "capture":
        return opts.capture == "walk"
    if key == "centre_wgs84":
        return opts.centre_wgs84 is not None
    return key not in ("query_tracks", "track_length") or opts.query_tracks > 0


def _render_tracks(
    scene: Scene,
    opts: WorldOptions,
    out: Path,
    intr: Intrinsics,
    f35: int,
    fmm: float,
    say: Callable[[str], None],
    t0: float,
) -> list[dict[str, Any]]:
    """Render and write the query tracks' frames (``track_TT_II``, kind ``track``); their manifest records."""
    shots, walks = sample_tracks(scene, opts, _centre(scene.map, opts))
    records = []
    for j, shot in enumerate(shots):
        name = f"track_{shot.walk_id:02d}_{shot.index:02d}"
        r = render(scene, shot.pose, intr, seed=opts.seed * 100_003 + 70_000 + j)
        gps, extra, phone = walk_photo(scene, shot, walks[shot.walk_id])
        phone = {k: v for k, v in phone.items() if k != "walk"} | {"track": shot.walk_id, "index": shot.index}
        phone["heading_mode"] = shot.heading_mode
        _write(out, "queries", name, r, gps, f35, fmm, opts, 20_000 + j, extra)
        records.append({**_image_record(scene, name, "query", "track", r, f35, fmm, gps, "queries"), **phone})
        if (j + 1) % 10 == 0 or j + 1 == len(shots):
            say(f"track frames {j + 1}/{len(shots)} ({time.perf_counter() - t0:.1f} s)")
    return records


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
    extra: dict[str, Any] | None = None,
) -> None:
    """Write one photo and its ground truth; ``extra``: more :func:`write_jpeg` fields (they win)."""
    fields: dict[str, Any] = {"taken": _taken(index), **(extra or {})}
    position = {"lat": gps["lat"], "lon": gps["lon"], "altitude": 12.0} if gps else {}
    exif = ExifFields(focal_35mm=f35, focal_mm=fmm, **position, **fields)
    write_jpeg(out / folder / f"{name}.jpg", r.rgb, exif, quality=opts.jpeg_quality)
    _save_gt(out / "gt" / f"{name}.npz", r)


def _taken(index: int) -> datetime:
    """The capture time of a scattered world's photo ``index`` (queries: 10,000 + their index)."""
    return datetime(2024, 6, 1, 10, 0, 0) + timedelta(seconds=37 * index)


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
