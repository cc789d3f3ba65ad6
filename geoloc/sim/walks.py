"""Worlds captured as people capture them: references taken on walks along the streets (``--capture walk``).

A walk follows the map's OSM highways (the street graph the scene's road raster is drawn from; a map
without highways is refused, since there is no street to walk on) from a random point inside the world's
disk, taking any branch at a junction other than the one it came from (turning back at a dead end, and
heading back towards the centre once outside the disk). The walker keeps to one side of the street, on
the pavement ``PAVEMENT_OFFSET_M`` from the centreline, moving closer to it wherever that would come
within ``CLEARANCE_M`` of a building. A photo is taken every 4-12 m of walking (``STEP_M``, with at
least 4 m between consecutive photos), at hand height (``CAMERA_HEIGHT_M``, per walker).

Where the camera looks (``HEADING_MIX``, a mode kept from one photo to the next with probability
``MODE_PERSISTENCE``): ``forward`` along the walk (+- 10 deg), ``across`` the street at the facades of
the far side (+- 15 deg), or ``near``: at the facades of the walker's own side, obliquely (50-80 deg off
the walking direction, since they are a few metres away).

The noise is a phone's, drawn per walk and recorded in the manifest:

- GPS: an offset correlated along the walk, per axis a first-order autoregression with correlation
  length ``GPS_CORRELATION_M`` (about 0.8 from one photo to the next) and stationary std ``GPS_STD_M``
  (3-8 m per walk), plus occasional 15-30 m jumps lasting 1-3 photos (probability ``JUMP_P`` per photo,
  ``JUMP_P_TALL`` within ``TALL_RADIUS_M`` of a building of ``TALL_HEIGHT_M`` or more).
- Compass: present on ``COMPASS_SHARE`` of the photos; per walk a true std ``COMPASS_STD_DEG`` (10-35 deg)
  split into a walk bias and a per-photo error, ``COMPASS_OUTLIER_P`` of the photos off by 45-180 deg;
  the accuracy the phone states is the true std times 0.8-1.25, rounded to a degree (phones state it
  roughly: the Lund photos say 21 and 35).
- Capture time: walks start 20 min apart (plus up to 5 min); between photos the walked distance at the
  walker's pace (1.1-1.5 m/s) plus a 1-4 s pause, to the millisecond.

Queries are sampled as in scattered worlds; ``QUERY_COMPASS_SHARE`` of them carry a compass with the same
noise model (:func:`query_compass`). Everything is deterministic for the generator passed in.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from geoloc.maps import CityMap
from geoloc.sim.options import WorldOptions
from geoloc.sim.pose import Pose
from geoloc.sim.scene import Scene

PHOTOS_PER_WALK = 15  # the number of walks is n_references / PHOTOS_PER_WALK, rounded, at least 1
STEP_M = (4.0, 12.0)
PAVEMENT_OFFSET_M = (3.0, 6.0)
CLEARANCE_M = 1.5
CAMERA_HEIGHT_M = (1.45, 1.65)
HEADING_MIX = {"forward": 0.4, "across": 0.45, "near": 0.15}
MODE_PERSISTENCE = 0.6
GPS_STD_M = (3.0, 8.0)
GPS_CORRELATION_M = 40.0
JUMP_M = (15.0, 30.0)
JUMP_P = 0.02
JUMP_P_TALL = 0.10
TALL_HEIGHT_M = 20.0
TALL_RADIUS_M = 30.0
COMPASS_SHARE = 0.85
COMPASS_STD_DEG = (10.0, 35.0)
COMPASS_OUTLIER_P = 0.04
SPEED_M_S = (1.1, 1.5)
PAUSE_S = (1.0, 4.0)
QUERY_COMPASS_SHARE = 0.5
FIRST_WALK_START = datetime(2024, 6, 1, 10, 0, 0)
_DENSE_M = 0.5  # the walked path is handled as points this far apart


class NoStreetsError(ValueError):
    """A walk world was asked of a map without streets (OSM highways) to walk along."""


@dataclass
class Walk:
    """One walk's person and phone: the noise parameters drawn for it (metres, degrees, seconds)."""

    walk_id: int
    sequence_uuid: str
    side: int  # +1: the walker keeps to the right of the street's direction of travel, -1 the left
    pavement_offset_m: float
    camera_height_m: float
    speed_m_s: float
    gps_std_m: float
    gps_accuracy_m: float  # what the phone states (GPSHPositioningError, MAPGPSAccuracyMeters)
    compass_std_deg: float  # the true std of the compass error
    compass_accuracy_deg: float  # what the phone states (MAPCompassHeading.AccuracyDegrees)
    compass_bias_deg: float

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, for the manifest's ``walks``."""
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


@dataclass
class Shot:
    """One reference photo of a walk: its true pose and every noise drawn for it."""

    pose: Pose
    walk_id: int
    index: int  # position in the walk, from 0
    heading_mode: str  # "forward", "across" or "near"
    gps_offset_m: tuple[float, float]  # the correlated offset (east, north), metres
    gps_jump_m: tuple[float, float]  # the jump added to it, (0, 0) when none
    compass_error_deg: float | None  # written heading - true heading; None: no compass
    compass_outlier: bool
    capture_time: datetime  # local time, to the millisecond


def n_walks(n_references: int) -> int:
    """How many walks take ``n_references`` photos."""
    return max(1, int(round(n_references / PHOTOS_PER_WALK)))


def _street_graph(city_map: CityMap) -> tuple[np.ndarray, list[list[int]]]:
    """The highways as a graph: (N, 2) node positions (local metres) and each node's neighbours.

    OSM ways share their junction nodes, so vertices at the same position (to the centimetre) are one node.
    """
    ids: dict[tuple[float, float], int] = {}
    nodes: list[np.ndarray] = []
    adj: list[list[int]] = []
    for line in city_map.streets:
        prev = -1
        for p in np.asarray(line, float):
            key = (round(float(p[0]), 2), round(float(p[1]), 2))
            node = ids.get(key)
            if node is None:
                node = ids[key] = len(nodes)
                nodes.append(p)
                adj.append([])
            if prev >= 0 and prev != node and node not in adj[prev]:
                adj[prev].append(node)
                adj[node].append(prev)
            prev = node
    return np.array(nodes).reshape(-1, 2), adj


def _centreline(
    nodes: np.ndarray,
    adj: list[list[int]],
    rng: np.random.Generator,
    length_m: float,
    centre: np.ndarray,
    radius_m: float,
) -> np.ndarray:
    """(M, 2) the nodes of a random walk on the street graph, at least ``length_m`` long where it can be."""
    a_idx = np.array([a for a in range(len(adj)) for b in adj[a] if b > a], dtype=np.int64)
    b_idx = np.array([b for a in range(len(adj)) for b in adj[a] if b > a], dtype=np.int64)
    seg_len = np.hypot(*(nodes[b_idx] - nodes[a_idx]).T)
    mid = (nodes[a_idx] + nodes[b_idx]) / 2
    w = seg_len * ((np.hypot(*(mid - centre).T) <= radius_m) if radius_m > 0 else 1.0)
    w = w if w.sum() > 0 else seg_len
    k = int(rng.choice(len(seg_len), p=w / w.sum()))
    prev, cur = (int(a_idx[k]), int(b_idx[k])) if rng.random() < 0.5 else (int(b_idx[k]), int(a_idx[k]))
    path, total = [prev, cur], float(seg_len[k])
    for _step in range(10_000):
        if total >= length_m:
            break
        options = [n for n in adj[cur] if n != prev] or [prev]
        if radius_m > 0 and np.hypot(*(nodes[cur] - centre)) > radius_m:
            nxt = min(options, key=lambda n: float(np.hypot(*(nodes[n] - centre))))
        else:
            nxt = options[int(rng.integers(len(options)))]
        total += float(np.hypot(*(nodes[nxt] - nodes[cur])))
        path.append(nxt)
        prev, cur = cur, nxt
    return nodes[path]


def _dense(line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A polyline resampled every ``_DENSE_M``: (M, 2) points and (M, 2) unit tangents, smoothed over ~6 m."""
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(line, axis=0).T))]
    t = np.arange(0.0, s[-1], _DENSE_M)
    pts = np.column_stack([np.interp(t, s, line[:, 0]), np.interp(t, s, line[:, 1])])
    half = 6
    padded = np.pad(pts, ((half, half), (0, 0)), mode="edge")
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    smooth = np.column_stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(2)])
    tan = np.gradient(smooth, axis=0)
    norm = np.hypot(*tan.T)
    raw = np.gradient(pts, axis=0)
    tan = np.where(
        norm[:, None] > 1e-6, tan / np.maximum(norm, 1e-12)[:, None], raw / np.maximum(np.hypot(*raw.T), 1e-12)[:, None]
    )
    return pts, tan


def _walked_path(scene: Scene, walk: Walk, pts: np.ndarray, tan: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The walker's path beside the centreline ``pts``: (M', 2) points and tangents, cut where no side is clear."""
    normal = np.column_stack([tan[:, 1], -tan[:, 0]]) * walk.side
    chosen = np.full(len(pts), np.nan)
    for factor in (1.0, 0.75, 0.5, 0.25, 0.0):
        todo = np.isnan(chosen)
        if not todo.any():
            break
        cand = pts[todo] + normal[todo] * walk.pavement_offset_m * factor
        ok = scene._clear_of_buildings(cand, CLEARANCE_M)
        idx = np.flatnonzero(todo)[ok]
        chosen[idx] = walk.pavement_offset_m * factor
    bad = np.flatnonzero(np.isnan(chosen))
    end = int(bad[0]) if len(bad) else len(pts)
    return pts[:end] + normal[:end] * chosen[:end, None], tan[:end]


def photo_indices(
    path: np.ndarray, rng: np.random.Generator, n_max: int, step_m: tuple[float, float] = STEP_M
) -> list[int]:
    """Indices of ``path`` where photos are taken: ``step_m`` (m) of walking apart, and as far apart in a line."""
    picked = [0]
    arc, step = 0.0, float(rng.uniform(step_m[0] + 1.0, step_m[1] - 2.0))
    for i in range(1, len(path)):
        if len(picked) >= n_max:
            break
        arc += float(np.hypot(*(path[i] - path[i - 1])))
        chord = float(np.hypot(*(path[i] - path[picked[-1]])))
        if arc >= step and step_m[0] <= chord <= step_m[1]:
            picked.append(i)
            arc, step = 0.0, float(rng.uniform(step_m[0] + 1.0, step_m[1] - 2.0))
    return picked


def _bearing_deg(v: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(v[0], v[1])) % 360.0)


def _yaw(mode: str, tangent: np.ndarray, side: int, rng: np.random.Generator) -> float:
    """Local bearing (deg) of the optical axis for a heading mode (module docstring)."""
    along = _bearing_deg(tangent)
    if mode == "forward":
        return (along + rng.normal(0.0, 10.0)) % 360.0
    if mode == "across":
        return (along - 90.0 * side + rng.normal(0.0, 15.0)) % 360.0
    return (along + side * rng.uniform(50.0, 80.0)) % 360.0


def _draw_walk(walk_id: int, rng: np.random.Generator) -> Walk:
    gps_std = float(rng.uniform(*GPS_STD_M))
    compass_std = float(rng.uniform(*COMPASS_STD_DEG))
    return Walk(
        walk_id=walk_id,
        sequence_uuid=str(uuid.UUID(bytes=rng.bytes(16), version=4)).upper(),
        side=int(rng.choice([-1, 1])),
        pavement_offset_m=float(rng.uniform(*PAVEMENT_OFFSET_M)),
        camera_height_m=round(float(rng.uniform(*CAMERA_HEIGHT_M)), 2),
        speed_m_s=float(rng.uniform(*SPEED_M_S)),
        gps_std_m=gps_std,
        gps_accuracy_m=float(round(gps_std * np.sqrt(2.0))),  # a radial figure, as phones state it
        compass_std_deg=compass_std,
        compass_accuracy_deg=float(round(compass_std * rng.uniform(0.8, 1.25))),
        compass_bias_deg=float(rng.normal(0.0, compass_std * 0.5)),
    )


def compass_error(
    rng: np.random.Generator, std_deg: float, bias_deg: float = 0.0, share: float = COMPASS_SHARE
) -> tuple[float | None, bool]:
    """One photo's compass error (deg) and whether it is an outlier; None when the photo has no compass.

    Without an outlier the error is ``bias_deg`` plus a normal draw whose std makes the total std
    ``std_deg`` when the bias has std ``std_deg / 2``; an outlier is off by 45-180 deg either way.
    """
    if rng.random() >= share:
        return None, False
    if rng.random() < COMPASS_OUTLIER_P:
        return float(rng.uniform(45.0, 180.0) * rng.choice([-1.0, 1.0])), True
    return float(bias_deg + rng.normal(0.0, std_deg * np.sqrt(0.75))), False


def query_compass(rng: np.random.Generator) -> tuple[float | None, bool, float, float]:
    """A query's compass: (error deg or None, outlier, true std deg, stated accuracy deg)."""
    std = float(rng.uniform(*COMPASS_STD_DEG))
    stated = float(round(std * rng.uniform(0.8, 1.25)))
    err, outlier = compass_error(rng, std, float(rng.normal(0.0, std * 0.5)), QUERY_COMPASS_SHARE)
    return err, outlier, std, stated


def _tall_near(scene: Scene) -> cKDTree | None:
    fac = scene.map.facades
    tall = scene.map.building_height_m[fac.building_id] >= TALL_HEIGHT_M
    if not tall.any():
        return None
    pts = np.concatenate([fac.start[tall], fac.end[tall], (fac.start[tall] + fac.end[tall]) / 2])
    return cKDTree(pts)


def _noise_and_times(
    walk: Walk, xy: np.ndarray, start: datetime, tall: cKDTree | None, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, list[datetime]]:
    """Per photo of one walk: (n, 2) correlated GPS offsets, (n, 2) jumps (metres), capture times."""
    n = len(xy)
    step = np.r_[0.0, np.hypot(*np.diff(xy, axis=0).T)]
    offset = np.zeros((n, 2))
    jump = np.zeros((n, 2))
    times = [start]
    jump_left, jump_vec = 0, np.zeros(2)
    for k in range(n):
        if k == 0:
            offset[k] = rng.normal(0.0, walk.gps_std_m, 2)
        else:
            rho = float(np.exp(-step[k] / GPS_CORRELATION_M))
            offset[k] = rho * offset[k - 1] + np.sqrt(1 - rho**2) * rng.normal(0.0, walk.gps_std_m, 2)
            pause = float(rng.uniform(*PAUSE_S))
            times.append(times[-1] + timedelta(milliseconds=int(round(1000 * (step[k] / walk.speed_m_s + pause)))))
        near_tall = tall is not None and bool(tall.query_ball_point(xy[k], TALL_RADIUS_M))
        if jump_left == 0 and rng.random() < (JUMP_P_TALL if near_tall else JUMP_P):
            ang = rng.uniform(0.0, 2 * np.pi)
            jump_vec = rng.uniform(*JUMP_M) * np.array([np.cos(ang), np.sin(ang)])
            jump_left = int(rng.integers(1, 4))
        if jump_left > 0:
            jump[k] = jump_vec
            jump_left -= 1
    return offset, jump, times


def sample_walks(
    scene: Scene, opts: WorldOptions, rng: np.random.Generator, centre: np.ndarray
) -> tuple[list[Shot], list[Walk]]:
    """``opts.n_references`` reference photos on walks (module docstring): the shots in walk order, the walks."""
    nodes, adj = _street_graph(scene.map)
    if not any(adj):
        raise NoStreetsError(f"{scene.map.source}: walk capture needs streets (OSM highways); this map has none")
    tall = _tall_near(scene)
    count = n_walks(opts.n_references)
    shots: list[Shot] = []
    walks: list[Walk] = []
    for _attempt in range(20 * count):
        left = opts.n_references - len(shots)
        if left <= 0:
            break
        walk_id = len(walks)
        want = min(left, int(np.ceil(left / max(1, count - walk_id))))
        walk = _draw_walk(walk_id, rng)
        line = _centreline(nodes, adj, rng, want * STEP_M[1] + 30.0, centre, opts.radius_m)
        pts, tan = _dense(line)
        path, path_tan = _walked_path(scene, walk, pts, tan)
        if len(path) < 2:
            continue
        picked = photo_indices(path, rng, want)
        if len(picked) < min(want, 3):
            continue  # a walk cut short by a building on the street: walk somewhere else
        walks.append(walk)
        start = FIRST_WALK_START + timedelta(minutes=20 * walk_id, seconds=float(rng.uniform(0.0, 300.0)))
        shots.extend(walk_shots(walk, path[picked], path_tan[picked], start, tall, opts, rng))
    return shots, walks


def walk_shots(
    walk: Walk,
    xy: np.ndarray,
    tangents: np.ndarray,
    start: datetime,
    tall: cKDTree | None,
    opts: WorldOptions,
    rng: np.random.Generator,
) -> list[Shot]:
    """The shots of one walk at its photo points ``xy`` (n, 2) with the path's unit ``tangents`` (n, 2).

    Draws the walk's heading modes, camera tilt, GPS noise, compass and capture times (module docstring);
    ``start``: the first photo's capture time (truncated to the millisecond).
    """
    start = start.replace(microsecond=(start.microsecond // 1000) * 1000)
    offset, jump, times = _noise_and_times(walk, xy, start, tall, rng)
    mode = str(rng.choice(list(HEADING_MIX), p=list(HEADING_MIX.values())))
    shots = []
    for k in range(len(xy)):
        if k > 0 and rng.random() >= MODE_PERSISTENCE:
            mode = str(rng.choice(list(HEADING_MIX), p=list(HEADING_MIX.values())))
        yaw = _yaw(mode, tangents[k], walk.side, rng)
        pitch = float(np.clip(rng.normal(0, opts.pitch_std_deg), -3 * opts.pitch_std_deg, 3 * opts.pitch_std_deg))
        roll = float(np.clip(rng.normal(0, opts.roll_std_deg), -3 * opts.roll_std_deg, 3 * opts.roll_std_deg))
        err, outlier = compass_error(rng, walk.compass_std_deg, walk.compass_bias_deg)
        pose = Pose(
            round(float(xy[k, 0]), 3),
            round(float(xy[k, 1]), 3),
            round(yaw, 3),
            round(pitch, 3),
            round(roll, 3),
            walk.camera_height_m,
        )
        gps = ((float(offset[k, 0]), float(offset[k, 1])), (float(jump[k, 0]), float(jump[k, 1])))
        shots.append(Shot(pose, walk.walk_id, k, mode, *gps, None if err is None else round(err, 3), outlier, times[k]))
    return shots


def mapillary_description(
    heading_deg: float | None,
    accuracy_deg: float | None,
    taken: datetime,
    sequence_uuid: str | None,
    gps_accuracy_m: float | None,
) -> str:
    """A Mapillary-style JSON for ImageDescription, as the Lund photos carry (compass only when given)."""
    doc: dict[str, Any] = {}
    if heading_deg is not None:
        doc["MAPCompassHeading"] = {"TrueHeading": round(heading_deg % 360.0, 4), "AccuracyDegrees": accuracy_deg}
    doc["MAPCaptureTime"] = taken.strftime("%Y_%m_%d_%H_%M_%S_") + f"{taken.microsecond // 1000:03d}"
    if sequence_uuid is not None:
        doc["MAPSequenceUUID"] = sequence_uuid
    if gps_accuracy_m is not None:
        doc["MAPGPSAccuracyMeters"] = f"{gps_accuracy_m:.6f}"
    return json.dumps(doc)
